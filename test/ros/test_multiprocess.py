"""Two OS processes exchange an Image and a PoseStamped over real DDS."""
import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.ros
PEERS = Path(__file__).with_name('peers.py')


def test_image_and_pose_cross_process_exactly():
    sys.path.insert(0, str(PEERS.parent))
    import peers

    listener = subprocess.Popen([sys.executable, str(PEERS), 'listener'], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    talker = subprocess.Popen([sys.executable, str(PEERS), 'talker'],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        out, err = listener.communicate(timeout=60)
    finally:
        talker.terminate()
        talker.wait(timeout=10)
        listener.kill()
    assert listener.returncode == 0, err
    received = json.loads(out.strip().splitlines()[-1])

    image = received['image']
    assert image['encoding'] == 'rgb8'
    assert image['shape'] == [48, 64, 3]
    assert image['sha256'] == hashlib.sha256(peers.known_image().tobytes()).hexdigest()
    assert image['frame_id'] == 'top_color_optical_frame'
    assert image['stamp'] == [1_700_000_000, 250_000_000]

    pose = received['pose']
    assert pose['frame_id'] == 'top_color_optical_frame'
    assert pose['stamp_ns'] == peers.STAMP_NS
    assert pose['position'] == [0.125, -0.05, 0.75]  # float64 on the wire: exact
    np.testing.assert_allclose(pose['T'], peers.known_transform(), atol=1e-12)

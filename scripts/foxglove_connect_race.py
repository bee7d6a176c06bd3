"""Does a Foxglove channel created while a client connects reach that client?

    python scripts/foxglove_connect_race.py [--trials 100] [--delay-s 0 0.001 0.005]

For each trial a WebSocket client connects to a foxglove-sdk server while another thread
creates a channel ``--delay-s`` later; the client then waits (1 s at most) for the channel's
advertisement, subscribes, and waits for one message logged on it. Counts the trials by
outcome: the channel never advertised, a status message from the server, no data, or ok.
The live view's test (test/nodes/test_foxglove_view.py) connects only once the pose's channel
exists; this checks whether the SDK itself loses a channel created during the connect.
"""
from __future__ import annotations

import argparse
import json
import threading
import time
from collections import Counter

import foxglove
from websockets.sync.client import connect

SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']


def _channel_later(topic: str, delay_s: float, made: list) -> threading.Thread:
    def make() -> None:
        time.sleep(delay_s)
        made.append(foxglove.Channel(topic, message_encoding='json'))
    thread = threading.Thread(target=make)
    thread.start()
    return thread


def one_trial(port: int, topic: str, delay_s: float) -> str:
    """'ok', 'not advertised', 'status' or 'no data' for one client and one new channel."""
    made: list = []
    maker = _channel_later(topic, delay_s, made)
    outcome = 'not advertised'
    with connect(f'ws://127.0.0.1:{port}', subprotocols=SUBPROTOCOLS) as socket:
        maker.join()
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline and outcome in ('not advertised', 'no data'):
            if outcome == 'no data':
                made[0].log(b'{"a": 1}')
            try:
                message = socket.recv(timeout=0.02)
            except TimeoutError:
                continue
            if isinstance(message, bytes):
                outcome = 'ok' if message[0] == 1 else outcome   # 1: message data
                continue
            reply = json.loads(message)
            if reply['op'] == 'status':
                outcome = 'status'
            elif reply['op'] == 'advertise' and topic in [c['topic'] for c in reply['channels']]:
                channel_id = next(c['id'] for c in reply['channels'] if c['topic'] == topic)
                socket.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                    {'id': 1, 'channelId': channel_id}]}))
                outcome = 'no data'
    made[0].close()
    return outcome


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--trials', type=int, default=100)
    parser.add_argument('--delay-s', type=float, nargs='+', default=[0.0, 0.001, 0.005])
    args = parser.parse_args()
    server = foxglove.start_server(name='race', host='127.0.0.1', port=0)
    try:
        for delay_s in args.delay_s:
            outcomes = Counter(one_trial(server.port, f'/race/{delay_s}/{k}', delay_s)
                               for k in range(args.trials))
            print(f'delay {delay_s * 1000:.1f} ms, {args.trials} trials: {dict(outcomes)}')
    finally:
        server.stop()


if __name__ == '__main__':
    main()

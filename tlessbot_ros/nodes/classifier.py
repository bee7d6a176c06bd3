"""classifier: names every localised instance with HOG + a linear model.

Subscribes (``input_qos``), for CAMERA in top, side:
    /CAMERA/color/image_raw                      sensor_msgs/Image (rgb8, bgr8, ...)
    /CAMERA/aligned_depth_to_color/image_raw     sensor_msgs/Image (metric shape features)
    /CAMERA/aligned_depth_to_color/camera_info   sensor_msgs/CameraInfo
    /localiser/CAMERA/labels                     sensor_msgs/Image 16UC1 instance labels
Publishes (RELIABLE, depth 10):
    classifier/CAMERA/classes    sensor_msgs/Image 16UC<k> class-instance labels,
                                 obj_id * 1000 + instance (0 * 1000 + i = unknown), channel c
                                 for the c-th best class (k = class_candidates; 16UC1 when 1);
                                 the scores of an instance are summed over the views that see
                                 it and written in both views (header = the labels' header)
    /diagnostics                 frames, failures, dropped, latency, last classes and margins
Parameters: ``model_path`` (.npz from ``tlessbot train``; default: the packaged model),
``reject_margin`` (margin below which a part is 'unknown'; 0 = the model's own),
``min_instance_px``, ``class_candidates``, ``top_view_verify_below_margin`` (for a part only the
top camera sees, the candidates after the first are sent only when the classifier is unsure),
``rig.CAMERA.*`` (extrinsics: heights above the table), ``sync.*``.
"""
from __future__ import annotations

from typing import Any

from tlessbot_ros.conversions import (
    camera_info_to_intrinsics,
    depth_image_to_metres,
    image_to_array,
    image_to_rgb,
    stamp_to_ns,
)
from tlessbot_ros.conversions.image_cdr import image_to_cdr
from tlessbot_ros.core.common import encode_candidates
from tlessbot_ros.core.pipeline import PerceptionPipeline, PipelineParams, ViewInput
from tlessbot_ros.core.recognise import load_classifier
from tlessbot_ros.data import DEFAULT_CLASSIFIER
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.nodes.common import RESULT_QOS, message_class, run_node
from tlessbot_ros.nodes.stage import CAMERAS, StageNode, declare_extrinsics, descriptor

IMAGE = 'sensor_msgs/msg/Image'


class ClassifierNode(StageNode):
    """Instance labels + colour -> class-instance labels."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('classifier', **kwargs)
        path = self.declare_parameter('model_path', str(DEFAULT_CLASSIFIER), descriptor(
            'Classifier .npz written by tlessbot train')).value
        reject = self.declare_parameter('reject_margin', 0.0, descriptor(
            'Classifier margin below which a part is unknown (0: the model default)')).value
        min_px = self.declare_parameter('min_instance_px', PipelineParams().min_instance_px,
                                        descriptor('Pixels an instance needs in a view to be '
                                                    'classified there')).value
        candidates = self.declare_parameter(
            'class_candidates', PipelineParams().class_candidates, descriptor(
                'Classes per part sent to the pose estimator, best first, as the channels of '
                'a 16UC<k> classes image (1: the classifier alone decides, 16UC1; at most 4)')
        ).value
        if not 1 <= int(candidates) <= 4:
            raise TlessbotError(f'class_candidates must be 1..4, got {candidates}')
        self.candidates = int(candidates)
        verify_below = self.declare_parameter(
            'top_view_verify_below_margin', PipelineParams().top_view_verify_below_margin,
            descriptor('For a part only the top camera sees, candidates after the first are '
                       "sent only when the margin is below this many times the model's median "
                       'training margin (inf: always)')).value
        self.extrinsics = declare_extrinsics(self)
        self.model = load_classifier(path)  # ModelFileError: one line, exit 1
        self.pipeline = PerceptionPipeline(
            classifier=self.model,
            params=PipelineParams(min_instance_px=int(min_px), reject_margin=float(reject),
                                  class_candidates=self.candidates,
                                  top_view_verify_below_margin=float(verify_below)))
        self._class_publishers = {
            camera: self.create_publisher(message_class(IMAGE), f'classifier/{camera}/classes',
                                          RESULT_QOS) for camera in CAMERAS}
        self.setup_inputs({
            'color': (IMAGE, '/{camera}/color/image_raw'),
            'depth': (IMAGE, '/{camera}/aligned_depth_to_color/image_raw'),
            'info': ('sensor_msgs/msg/CameraInfo', '/{camera}/aligned_depth_to_color/camera_info'),
            'labels': (IMAGE, '/localiser/{camera}/labels')})
        self.get_logger().info(f'loaded {self.model.kind} classifier for '
                               f'{len(self.model.class_ids)} objects from {path}')

    def process(self, views: dict[str, dict[str, Any]]) -> None:
        rgb = {camera: image_to_rgb(msgs['color']) for camera, msgs in views.items()}
        labels = {}
        for camera, msgs in views.items():
            if msgs['labels'].encoding not in ('16UC1', 'mono16'):
                raise ValueError(f'labels must be 16UC1, got {msgs["labels"].encoding!r}')
            labels[camera] = image_to_array(msgs['labels'])
            if labels[camera].shape != rgb[camera].shape[:2]:
                raise ValueError(f'{camera}: labels {labels[camera].shape} and colour '
                                 f'{rgb[camera].shape[:2]} sizes differ')
        views_in = {camera: ViewInput(
            rgb=rgb[camera], depth_m=depth_image_to_metres(msgs['depth']),
            intrinsics=camera_info_to_intrinsics(msgs['info']),
            T_world_camera=self.extrinsics[camera]) for camera, msgs in views.items()}
        guesses = self.pipeline.classify(rgb, labels, views=views_in)
        candidates = {instance: guess.candidates for instance, guess in guesses.items()}
        encoding = f'16UC{self.candidates}'
        for camera, msgs in views.items():
            header = msgs['labels'].header
            self._class_publishers[camera].publish(image_to_cdr(   # raw CDR: one copy
                encode_candidates(labels[camera], candidates, self.candidates), encoding,
                frame_id=header.frame_id, stamp_ns=stamp_to_ns(header.stamp)))


def main(args: list[str] | None = None) -> None:
    run_node(ClassifierNode, args)


if __name__ == '__main__':
    main()

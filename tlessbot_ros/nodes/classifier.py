"""classifier: names every localised instance with HOG + a linear model.

Subscribes (``input_qos``), for CAMERA in top, side:
    /CAMERA/color/image_raw                      sensor_msgs/Image (rgb8, bgr8, ...)
    /CAMERA/aligned_depth_to_color/image_raw     sensor_msgs/Image (metric shape features)
    /CAMERA/aligned_depth_to_color/camera_info   sensor_msgs/CameraInfo
    /localiser/CAMERA/labels                     sensor_msgs/Image 16UC1 instance labels
Publishes (RELIABLE, depth 10):
    classifier/CAMERA/classes    sensor_msgs/Image 16UC<k> class-instance labels,
                                 obj_id * 1000 + instance (0 * 1000 + i = unknown), channel c
                                 for the c-th best class (k = class_candidates; 16UC1 when 1;
                                 up to 4 for unsure parts with ``fit_rank_below_margin``);
                                 the scores of an instance are summed over the views that see
                                 it and written in both views (header = the labels' header)
    /diagnostics                 frames, failures, dropped, latency, last classes and margins
Parameters: ``parts_path`` (a parts folder of ``tlessbot parts build``; read-only),
``model_path`` (.npz from ``tlessbot train``; default: the parts folder's, else packaged),
``reject_margin`` (margin below which a part is 'unknown'; 0 = the model's own),
``min_instance_px``, ``class_candidates``, ``top_view_verify_below_margin`` (for a part only the
top camera sees, the candidates after the first are sent only when the classifier is unsure;
all four: ClassifyParams), ``rig.cameras`` (the names of the top and side cameras),
``rig.CAMERA.*`` (extrinsics: heights above the table), ``rig_source`` ('localiser': the
camera poses the localiser publishes on /localiser/rig replace ``rig.CAMERA.*`` once it refines
the rig; 'config'), ``sync.*``. All are live (``ros2
param set``, from the next frame; a new ``model_path`` is loaded at once, or refused, and used
once warmed up) but ``rig.cameras``, ``rig_source``, ``input_qos``, ``input_depth``,
``sync.worker_thread``, ``sync.executor``.
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
from tlessbot_ros.conversions.image_cdr import image_from_cdr, image_to_cdr
from tlessbot_ros.conversions.topics import classes_topic, labels_topic, node_relative
from tlessbot_ros.core.by_fit import candidate_channels
from tlessbot_ros.core.common import encode_candidates
from tlessbot_ros.core.pipeline import ClassifyParams, PerceptionPipeline, ViewInput
from tlessbot_ros.core.recognise import Classifier, load_classifier
from tlessbot_ros.data import DEFAULT_CLASSIFIER
from tlessbot_ros.nodes.common import RESULT_QOS, message_class, run_node
from tlessbot_ros.nodes.parts import declare_parts
from tlessbot_ros.nodes.stage import (
    IMAGE,
    StageNode,
    camera_inputs,
    follow_observed_rig,
)

LABEL_ENCODINGS = ('16UC1', 'mono16')


class ClassifierNode(StageNode):
    """Instance labels + colour -> class-instance labels."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('classifier', after_localiser=True, **kwargs)
        parts = declare_parts(self)   # PartsFolderError: one line, exit 1
        self.model = self.parameters.group(   # ModelFileError: one line, exit 1
            {'model_path': (str(parts.classifier if parts else DEFAULT_CLASSIFIER),
                            "Classifier .npz; default: the parts folder's, else the "
                            'packaged one')},
            build=lambda values: load_classifier(values['model_path']),
            warm=self._warm_model, apply=self._apply_model)
        path = self.get_parameter('model_path').value
        self.classify_params = self.parameters.dataclass(ClassifyParams(),
                                                         apply=self._apply_classify_params)
        self.candidates = _channels(self.classify_params)
        self.pipeline = PerceptionPipeline(classifier=self.model,
                                           classify_params=self.classify_params)
        self._class_publishers = {
            camera: self.create_publisher(message_class(IMAGE),
                                          node_relative(classes_topic(camera)), RESULT_QOS)
            for camera in self.cameras}
        self.get_logger().info(f'loaded {self.model.kind} classifier for '
                               f'{len(self.model.class_ids)} objects from {path}')
        self.rig_source = follow_observed_rig(self)
        inputs = camera_inputs(('color', 'depth', 'info'), self.input_source)
        self.start_when_ready(self._warm_up, {**inputs, 'labels': (IMAGE, labels_topic)})

    def _warm_up(self, pipeline: PerceptionPipeline | None = None) -> None:
        """Classify the box of a synthetic frame once (HOG, shape features, feature map) with
        ``pipeline`` (default: the node's) and encode its classes, from labels read as a
        frame's arrive (read-only views of CDR bytes: the numba kernels compile for them)."""
        views, labels = self.warm_up_frame()
        received = {camera: image_to_array(image_from_cdr(image_to_cdr(image, '16UC1')))
                    for camera, image in labels.items()}
        guesses = (pipeline or self.pipeline).classify({c: v.rgb for c, v in views.items()},
                                                       received, views=views)
        encode_candidates(received[self.cameras[0]],
                          {i: g.candidates for i, g in guesses.items()}, self.candidates)

    def _warm_model(self, model: Classifier) -> None:
        """A new model's first classification, off the frame thread (``model_path`` set)."""
        self._warm_up(PerceptionPipeline(classifier=model, classify_params=self.classify_params))

    def _apply_model(self, model: Classifier) -> None:
        self.model, self.pipeline = model, self.pipeline.replace(classifier=model)
        self.get_logger().info(f'now classifying with the {model.kind} classifier for '
                               f'{len(model.class_ids)} objects')

    def _apply_classify_params(self, params: ClassifyParams) -> None:
        self.classify_params, self.candidates = params, _channels(params)
        self.pipeline = self.pipeline.replace(classify_params=params)

    def process(self, views: dict[str, dict[str, Any]]) -> None:
        rgb = {camera: image_to_rgb(msgs['color']) for camera, msgs in views.items()}
        labels = {camera: _labels(camera, msgs['labels'], rgb[camera].shape[:2])
                  for camera, msgs in views.items()}
        views_in = {camera: ViewInput(
            rgb=rgb[camera], depth_m=depth_image_to_metres(msgs['depth']),
            intrinsics=camera_info_to_intrinsics(msgs['info']),
            T_world_camera=self.camera_pose(camera)) for camera, msgs in views.items()}
        guesses = self.pipeline.classify(rgb, labels, views=views_in)
        candidates = {instance: guess.candidates for instance, guess in guesses.items()}
        encoding = f'16UC{self.candidates}'
        for camera, msgs in views.items():
            header = msgs['labels'].header
            self._class_publishers[camera].publish(image_to_cdr(   # raw CDR: one copy
                encode_candidates(labels[camera], candidates, self.candidates), encoding,
                frame_id=header.frame_id, stamp_ns=stamp_to_ns(header.stamp)))


def _labels(camera: str, msg: Any, shape: tuple[int, int]) -> Any:
    """The (H, W) instance labels of a labels Image, checked against the colour image's size."""
    if msg.encoding not in LABEL_ENCODINGS:
        raise ValueError(f'labels must be 16UC1, got {msg.encoding!r}')
    labels = image_to_array(msg)
    if labels.shape != shape:
        raise ValueError(f'{camera}: labels {labels.shape} and colour {shape} sizes differ')
    return labels


def _channels(params: ClassifyParams) -> int:
    """Candidate channels sent per part (``class_candidates``; more with fit ranking on)."""
    return candidate_channels(params.class_candidates, params.fit_rank_below_margin,
                              params.fit_rank_max_candidates)


def main(args: list[str] | None = None) -> None:
    run_node(ClassifierNode, args)


if __name__ == '__main__':
    main()

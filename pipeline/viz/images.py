"""The images in the Rerun sink: the log's left image at a replayed pose, the front-end's image
with its tag outlines, each detection's box labelled with class, score, range and (on replay)
the landmark it went to; and the front-end's detections in the body frame.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from pipeline.geometry import point_from_bearing_elevation_range
from pipeline.viz import draw
from pipeline.viz import entities as e

if TYPE_CHECKING:
    from pipeline.log.messages import Detection
    from pipeline.viz.frontend import FrontendKeyframe

MEDIA_TYPES = {"jpeg": "image/jpeg", "jpg": "image/jpeg", "png": "image/png"}


class ImageView:
    """The images' part of `RerunSink` (its state is the sink's)."""

    def _log_image(self, pose_index: int, detections: list[tuple[Detection, int | None]]) -> None:
        """The log's left image at this pose, each detection's box labelled with its reported
        class, score and the landmark it went to."""
        every = self.config.image_every
        if not self._images or every == 0 or pose_index % every:
            return
        image = self._images.get(self._stamp(pose_index))
        if image is None:
            return
        media_type = MEDIA_TYPES.get(image.format.lower())
        self.rec.log(e.CAMERA, rr.EncodedImage(contents=image.data, media_type=media_type))
        self._log_boxes([(d, winner) for d, winner in detections if d.bbox is not None])

    def _log_boxes(self, boxes: list[tuple[Detection, int | None]]) -> None:
        """Boxes coloured by reported class, labelled with class, score, range and (on replay)
        the landmark each went to."""
        if boxes:
            labels = [
                draw.detection_label(d, self._class_names[d.class_id], winner)
                for d, winner in boxes
            ]
            self.rec.log(
                e.CAMERA_DETECTIONS,
                rr.Boxes2D(
                    array=[d.bbox for d, _ in boxes],
                    array_format=rr.Box2DFormat.XYXY,
                    class_ids=[d.class_id for d, _ in boxes],
                    labels=labels,
                ),
            )
        self._clear_unless(e.CAMERA_DETECTIONS, bool(boxes))

    def _log_body_detections(self, detections: list[Detection]) -> None:
        """A keyframe's detections in the body frame (children of the robot), coloured by class
        and labelled with class, score and range."""
        if detections:
            body = point_from_bearing_elevation_range(
                np.array([[d.bearing, d.elevation, d.range] for d in detections])
            )
            names = self._class_names
            self.rec.log(
                e.ROBOT_DETECTIONS,
                rr.Points3D(
                    body,
                    class_ids=[d.class_id for d in detections],
                    labels=[draw.detection_label(d, names[d.class_id]) for d in detections],
                    radii=rr.Radius.ui_points(4.0),
                ),
            )
        self._clear_unless(e.ROBOT_DETECTIONS, bool(detections))

    def _log_frontend_image(self, keyframe: FrontendKeyframe) -> None:
        import cv2

        quality = [cv2.IMWRITE_JPEG_QUALITY, self.config.jpeg_quality]
        ok, data = cv2.imencode(".jpg", keyframe.left, quality)
        if ok:
            self.rec.log(
                e.CAMERA, rr.EncodedImage(contents=data.tobytes(), media_type="image/jpeg")
            )
        tags = keyframe.tags
        if tags:
            self.rec.log(
                e.CAMERA_TAGS,
                rr.LineStrips2D(
                    [np.vstack([t.corners, t.corners[:1]]) for t in tags],
                    labels=[
                        f"tag {t.tag_id}"
                        if t.detection is None
                        else draw.detection_label(t.detection, f"tag {t.tag_id}")
                        for t in tags
                    ],
                    colors=[
                        draw.packed_rgba(draw.ESTIMATE_RGB)
                        if t.detection is None
                        else self._colours[t.detection.class_id]
                        for t in tags
                    ],
                    radii=rr.Radius.ui_points(2.0),
                ),
            )
        self._clear_unless(e.CAMERA_TAGS, bool(tags))
        # Tags are drawn by their outlines where the front-end gave them; boxes for the rest.
        outlined = {id(t.detection) for t in tags if t.detection is not None}
        self._log_boxes(
            [(d, None) for d in keyframe.detections if d.bbox is not None and id(d) not in outlined]
        )

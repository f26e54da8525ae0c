"""The face every results sink shows the pipeline."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import numpy as np

    from pipeline.backend.slam import BackendResult, KeyframeReport
    from pipeline.log.messages import DetectionLog, LogMetadata
    from pipeline.viz.frontend import FrontendKeyframe


class Sink(Protocol):
    """Sees a replay: its log, each keyframe's report (with the back-end's map, read-only)
    and the seconds the back-end took for it, then the result."""

    wants_images: bool  # replay loads the log's images only for a sink that shows them

    def start(self, log: DetectionLog, method: str) -> None: ...

    def keyframe(self, report: KeyframeReport, seconds: float) -> None: ...

    def finish(self, result: BackendResult, metrics: dict[str, Any] | None) -> None: ...

    def close(self) -> None: ...


class NullSink:
    """Shows nothing, costs nothing: a replay's sink (`Sink`) and a front-end run's
    (`pipeline.viz.frontend.FrontendSink`) when nothing is viewed."""

    wants_images = False

    def start(self, log: DetectionLog, method: str) -> None:
        pass

    def keyframe(self, report: KeyframeReport, seconds: float) -> None:
        pass

    def finish(self, result: BackendResult, metrics: dict[str, Any] | None) -> None:
        pass

    def frontend_start(self, metadata: LogMetadata, extent: np.ndarray | None = None) -> None:
        pass

    def frontend_keyframe(self, keyframe: FrontendKeyframe) -> None:
        pass

    def frontend_finish(self) -> None:
        pass

    def close(self) -> None:
        pass


class TeeSink:
    """Several sinks as one (a Rerun recording and a Foxglove file, say)."""

    def __init__(self, sinks: list[Sink]):
        self.sinks = sinks
        self.wants_images = any(s.wants_images for s in sinks)

    def start(self, log: DetectionLog, method: str) -> None:
        for sink in self.sinks:
            sink.start(log, method)

    def keyframe(self, report: KeyframeReport, seconds: float) -> None:
        for sink in self.sinks:
            sink.keyframe(report, seconds)

    def finish(self, result: BackendResult, metrics: dict[str, Any] | None) -> None:
        for sink in self.sinks:
            sink.finish(result, metrics)

    def close(self) -> None:
        for sink in self.sinks:
            sink.close()

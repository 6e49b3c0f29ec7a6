"""An mp4 video read safely, as the IntPhys 2 reader needs it: which frames of a video of any
length become a clip (``ClipSampling``), and the sampled frames decoded with PyAV, refusing a
damaged file rather than scoring what FFmpeg conceals (``read_video``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from voe_lightning.benchmarks.reader import BenchmarkDataError, FrameSampling, frame_indices


@dataclass(frozen=True)
class ClipSampling:
    """Which frames of a video of any length become the model's ``len(video.indices)`` frames:
    every ``frame_step``-th from ``first_frame``, or, with ``frame_step`` None, spread evenly
    over the whole video; ``video`` gives the size and the divergence thresholds."""

    video: FrameSampling
    frame_step: int | None = None
    first_frame: int = 0

    @property
    def num_frames(self) -> int:
        return len(self.video.indices)

    def indices(self, available: int, path: Path) -> np.ndarray:
        try:
            return frame_indices(available, self.num_frames, self.frame_step, self.first_frame)
        except ValueError as error:
            raise BenchmarkDataError(f"{path}: {error}", "too_short") from None


def read_video(path: Path, sampling: ClipSampling) -> np.ndarray:
    """The sampled frames of an mp4 at full resolution, uint8 [T, h, w, 3], decoded with PyAV.
    Frames are picked while decoding (``_decode``), so a long video is never held whole. A
    damaged file is refused, never scored: one that does not open, that holds a packet FFmpeg
    flags corrupt, that FFmpeg reports errors in while decoding (PyAV drops FFmpeg's log
    unless asked, and FFmpeg conceals a damaged packet, so a truncated or corrupted mp4 would
    decode to other frames in silence), or that decodes fewer frames than its header states.
    PyAV is imported here, so the package imports without it (on a machine that trains on
    generated data alone)."""
    import av
    import av.logging

    level, skip_repeated = av.logging.get_level(), av.logging.get_skip_repeated()
    av.logging.set_level(av.logging.ERROR)
    av.logging.set_skip_repeated(False)  # the same damage in the next file is news too
    try:
        # Not only this thread's messages: FFmpeg's decoding threads log the damage.
        with av.logging.Capture(local=False) as logs:
            frames, count, stated = _decode(path, sampling)
    except BenchmarkDataError:
        raise
    except FileNotFoundError:
        raise BenchmarkDataError(f"missing video {path}", "missing_file") from None
    except (av.FFmpegError, OSError, ValueError) as error:
        raise BenchmarkDataError(
            f"{path} does not decode ({type(error).__name__}: {error}); expected an mp4 video",
            "undecodable_video",
        ) from None
    finally:
        av.logging.set_level(level)
        av.logging.set_skip_repeated(skip_repeated)
    errors = [message.strip() for severity, _, message in logs if severity <= av.logging.ERROR]
    if errors:
        raise BenchmarkDataError(
            f"{path} is damaged: FFmpeg reports {errors[0]!r} decoding it ({len(errors)} "
            "error(s)); expected an intact mp4 video",
            "undecodable_video",
        )
    if count < stated:
        raise BenchmarkDataError(
            f"{path} is truncated or damaged: {count} of the {stated} frames its header states "
            "decode; expected an intact mp4 video",
            "undecodable_video",
        )
    if len(frames) != sampling.num_frames:
        raise BenchmarkDataError(
            f"{path} has no decodable frames; expected an mp4 video", "undecodable_video"
        )
    return np.stack(frames)


def _decode(path: Path, sampling: ClipSampling) -> tuple[list[np.ndarray], int, int]:
    """The frames ``sampling`` picks from the mp4 at ``path``, the number of frames decoded
    and the number its header states (0: none stated). The picks come from the stated count;
    where the header states none, or fewer than decode, the video is decoded again with the
    picks from the count decoded."""
    import av

    def decode(available: int) -> tuple[list[np.ndarray], int]:
        wanted = set(sampling.indices(available, path).tolist()) if available else set()
        kept, count = [], 0
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise BenchmarkDataError(
                    f"{path} holds no video stream; expected an mp4 video", "undecodable_video"
                )
            for number, packet in enumerate(container.demux(container.streams.video[0])):
                if packet.is_corrupt:  # cut short: FFmpeg only warns, and decodes what is left
                    raise BenchmarkDataError(
                        f"{path} is damaged: its video packet {number} is corrupt (cut "
                        "short?); expected an intact mp4 video",
                        "undecodable_video",
                    )
                for frame in packet.decode():
                    if count in wanted:
                        kept.append(frame.to_ndarray(format="rgb24"))
                    count += 1
        return kept, count

    with av.open(str(path)) as container:
        stated = container.streams.video[0].frames if container.streams.video else 0
    frames, count = decode(stated)
    if count > stated:
        frames, count = decode(count)
    return frames, count, stated

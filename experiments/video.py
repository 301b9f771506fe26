"""A video of one agent's episode on ``SixAxisTrack-v0``: the arm, the reference path (green), the
true tool point's path (blue) and the tracker's measured points (red).

    info = render_episode(make_agent("mpc"), "geometric", seed=0, path="run.mp4")
    info.frames, info.seconds          # 500 frames, 10 s at 50 frames per second

Frames are rendered offscreen by MuJoCo (``MUJOCO_GL=egl`` or ``osmesa``; no shadows, no
multisampling) and streamed to ffmpeg (the binary that ``imageio-ffmpeg`` ships) as H.264 in an
MP4 file, one frame per ``every`` control steps, so the video runs in real time: its duration is
the episode's. The file is written to a temporary name and renamed when complete
(:func:`arm.files.atomic_path`): an existing directory, device or FIFO at the path is refused,
not replaced.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from arm.files import atomic_path, check_output
from experiments.errors import VideoError

__all__ = ["MAX_FRAME", "VideoError", "VideoInfo", "render_episode"]

MAX_FRAME = 4096  # pixels a side, as the env renders (envs.sixaxis_track_v0.MAX_FRAME)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class VideoInfo:
    path: Path
    frames: int
    fps: float
    width: int
    height: int

    @property
    def seconds(self) -> float:
        return self.frames / self.fps


def _writer():
    try:
        import imageio_ffmpeg  # type: ignore[import-untyped]
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        raise VideoError(
            "writing videos needs the 'video' extra: pip install 'sixaxis-track[video]'"
        ) from exc
    return imageio_ffmpeg


def render_episode(
    agent: Any,
    scenario: str,
    seed: int,
    path: str | Path,
    seconds: float = 10.0,
    every: int = 1,
    width: int = 640,
    height: int = 480,
    env_kwargs: Mapping[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> VideoInfo:
    """Run ``agent`` for ``seconds`` on ``scenario`` with ``seed`` and write the video to
    ``path`` (MP4); see the module docstring. ``progress(frames_done, frames_total)``."""
    from agents.runner import run_episode

    if not (16 <= width <= MAX_FRAME and 16 <= height <= MAX_FRAME) or width % 2 or height % 2:
        raise VideoError(
            f"width and height must be even, from 16 to {MAX_FRAME} pixels, got {width}x{height}"
        )
    if int(every) != every or every < 1:
        raise VideoError(f"every must be a positive integer (control steps), got {every}")
    if not seconds > 0:
        raise VideoError(f"seconds must be positive, got {seconds}")
    out = Path(path)
    if out.suffix.lower() != ".mp4":
        raise VideoError(f"{out}: the video is written as MP4; give a file ending in .mp4")
    check_output(out, stdout_ok=False)
    ffmpeg = _writer()
    kwargs = dict(env_kwargs or {}) | {
        "scenario": scenario,
        "render_mode": "rgb_array",
        "width": int(width),
        "height": int(height),
        "episode_seconds": max(float(seconds), 10.0),
    }
    state = {"step": 0, "frames": 0}
    fps = 0.0
    total: int | None = None
    writer = None

    def encode(send: Callable[[], Any]) -> None:
        """ffmpeg's own failure (a full disk, a frame it refuses) as one VideoError."""
        try:
            send()
        except (OSError, RuntimeError) as exc:
            raise VideoError(f"{out}: ffmpeg could not encode the video ({exc})") from None

    def on_step(env) -> None:
        nonlocal writer, total, fps
        state["step"] += 1
        if state["step"] % every:
            return
        frame = env.render()
        if writer is None:
            dt = float(env.unwrapped.task.dt)
            fps = 1.0 / (dt * every)
            total = round(seconds / dt) // every
            writer = ffmpeg.write_frames(
                str(tmp),
                (int(width), int(height)),
                fps=fps,
                codec="libx264",
                pix_fmt_out="yuv420p",
                macro_block_size=2,
                quality=7,
                output_params=["-movflags", "+faststart", "-f", "mp4"],
            )
        current = writer
        if state["frames"] == 0:
            encode(lambda: current.send(None))  # start ffmpeg
        encode(lambda: current.send(frame))
        state["frames"] += 1
        if progress is not None:
            progress(state["frames"], total or state["frames"])

    with atomic_path(out) as tmp:
        try:
            run_episode(
                agent, kwargs, seed=int(seed), episode_seconds=float(seconds), on_step=on_step
            )
            if writer is None:
                raise VideoError(
                    f"the episode gave no frame ({seconds} s, one frame every {every} steps)"
                )
            done, writer = writer, None
            encode(done.close)
        finally:
            if writer is not None:
                with contextlib.suppress(Exception):
                    writer.close()
    log.info("wrote %s: %d frames at %g fps", out, state["frames"], fps)
    return VideoInfo(out, int(state["frames"]), float(fps), int(width), int(height))

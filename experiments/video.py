"""A video of one agent's episode on ``SixAxisTrack-v0``: the arm, the reference path (green), the
true tool point's path (blue) and the tracker's measured points (red).

    info = render_episode(make_agent("mpc"), "geometric", seed=0, path="run.mp4")
    info.frames, info.seconds          # 500 frames, 10 s at 50 frames per second

Frames are rendered offscreen by MuJoCo (``MUJOCO_GL=egl`` or ``osmesa``; no shadows, no
multisampling) and streamed to ffmpeg (the binary that ``imageio-ffmpeg`` ships) as H.264 in an
MP4 file, one frame per ``every`` control steps, so the video runs in real time: its duration is
the episode's. The file is written to a temporary name and renamed when complete.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from arm.errors import SixAxisError

__all__ = ["VideoError", "VideoInfo", "render_episode"]

log = logging.getLogger(__name__)


class VideoError(SixAxisError, ValueError):
    """Video settings that cannot be written (frame size, rate), or no video writer installed."""


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
        import imageio_ffmpeg
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

    if width < 16 or height < 16 or width % 2 or height % 2:
        raise VideoError(f"width and height must be even and at least 16, got {width}x{height}")
    if int(every) != every or every < 1:
        raise VideoError(f"every must be a positive integer (control steps), got {every}")
    if not seconds > 0:
        raise VideoError(f"seconds must be positive, got {seconds}")
    ffmpeg = _writer()
    out = Path(path)
    tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp{out.suffix or '.mp4'}")
    kwargs = dict(env_kwargs or {}) | {
        "scenario": scenario,
        "render_mode": "rgb_array",
        "width": int(width),
        "height": int(height),
        "episode_seconds": max(float(seconds), 10.0),
    }
    state = {"step": 0, "frames": 0, "fps": None}
    total = None
    writer = None

    def on_step(env) -> None:
        nonlocal writer, total
        state["step"] += 1
        if state["step"] % every:
            return
        if writer is None:
            dt = float(env.unwrapped.task.dt)
            state["fps"] = 1.0 / (dt * every)
            total = round(seconds / dt) // every
            writer = ffmpeg.write_frames(
                str(tmp),
                (int(width), int(height)),
                fps=state["fps"],
                codec="libx264",
                pix_fmt_out="yuv420p",
                macro_block_size=2,
                quality=7,
                output_params=["-movflags", "+faststart"],
            )
            writer.send(None)  # start ffmpeg
        writer.send(env.render())
        state["frames"] += 1
        if progress is not None:
            progress(state["frames"], total or state["frames"])

    try:
        run_episode(agent, kwargs, seed=int(seed), episode_seconds=float(seconds), on_step=on_step)
        if writer is None:
            raise VideoError(
                f"the episode gave no frame ({seconds} s, one frame every {every} steps)"
            )
        writer.close()
        writer = None
        os.replace(tmp, out)
    finally:
        if writer is not None:
            writer.close()
        tmp.unlink(missing_ok=True)
    log.info("wrote %s: %d frames at %g fps", out, state["frames"], state["fps"])
    return VideoInfo(out, int(state["frames"]), float(state["fps"]), int(width), int(height))

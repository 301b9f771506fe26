"""Videos: Gymnasium's RecordVideo works on the env out of the box, and ``sixaxis render`` writes
a playable MP4 of any agent's episode, as long as the episode, with the reference, the true tool
path and the measured points drawn in."""

from __future__ import annotations

import gymnasium as gym
import imageio_ffmpeg
import numpy as np
import pytest
from gymnasium.wrappers import RecordVideo
from typer.testing import CliRunner

import envs  # noqa: F401
from experiments.cli import app


def decode(path) -> tuple[dict, list[np.ndarray]]:
    """Every frame of a video, decoded by ffmpeg (an independent reader)."""
    gen = imageio_ffmpeg.read_frames(str(path))
    meta = next(gen)
    w, h = meta["size"]
    return meta, [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in gen]


def test_record_video_writes_a_playable_episode(tmp_path):
    env = gym.make("SixAxisTrack-v0", render_mode="rgb_array", width=160, height=120)
    folder = tmp_path / "videos"
    env = RecordVideo(env, str(folder), episode_trigger=lambda e: True, disable_logger=True)
    env.reset(seed=0)
    for _ in range(24):
        env.step(np.zeros(6))
    env.close()
    (video,) = folder.glob("*.mp4")
    nframes, secs = imageio_ffmpeg.count_frames_and_secs(str(video))
    assert nframes == 25  # the reset's frame and one per step
    assert secs == pytest.approx(25 / 50, abs=0.021)  # the env's 50 frames per second


def test_sixaxis_render_writes_a_video_of_the_episode(tmp_path):
    out = tmp_path / "run.mp4"
    args = [
        "render",
        "nominal",
        "--scenario",
        "geometric",
        "--seed",
        "1",
        "--episode-seconds",
        "0.6",
    ]
    args += ["--width", "160", "--height", "120", "-o", str(out)]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "30 frames, 0.60 s at 50 fps" in " ".join(res.output.split())
    nframes, secs = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert (nframes, secs) == (30, pytest.approx(0.6, abs=0.021))
    meta, frames = decode(out)
    assert meta["size"] == (160, 120) and meta["fps"] == pytest.approx(50)
    assert len(frames) == 30 and frames[-1].std() > 10  # a picture, not a blank
    assert not list(tmp_path.glob(".*"))  # no temporary file left
    # every other step: half the frames at 25 fps, the same duration
    res = CliRunner().invoke(app, [*args[:-1], str(tmp_path / "half.mp4"), "--every", "2"])
    assert res.exit_code == 0, res.output
    nframes, secs = imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "half.mp4"))
    assert (nframes, secs) == (15, pytest.approx(0.6, abs=0.041))


def test_frames_draw_the_reference_the_true_tool_path_and_the_measurements():
    green, blue, red = (0.05, 0.7, 0.2, 1.0), (0.1, 0.3, 0.95, 1.0), (0.85, 0.05, 0.05, 1.0)
    env = gym.make("SixAxisTrack-v0", render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    for _ in range(30):
        env.step(np.full(6, 0.2))
    env.render()
    scn = env.unwrapped._renderer.scene
    rgba = [tuple(np.round(scn.geoms[i].rgba, 2)) for i in range(scn.ngeom)]
    assert rgba.count(green) > 100  # the reference path
    assert rgba.count(blue) == 1 + 15  # the tool now, and 30 steps of its path (every other)
    assert rgba.count(red) == 6  # the measurements of 30 steps, one every 5
    env.close()


def test_render_refuses_bad_settings_clearly(tmp_path):
    res = CliRunner().invoke(
        app, ["render", "hold", "--width", "161", "-o", str(tmp_path / "x.mp4")]
    )
    assert res.exit_code == 2 and "even" in res.output
    res = CliRunner().invoke(app, ["render", "bogus", "-o", str(tmp_path / "x.mp4")])
    assert res.exit_code == 2 and "unknown agent 'bogus'" in res.output
    assert not list(tmp_path.iterdir())

"""Offscreen rendering of env trajectories (any registered env) to frames, GIF or MP4.

Needs an OpenGL backend: on a headless Linux machine set ``MUJOCO_GL=egl`` (packages ``libegl1`` + ``libgl1``; with a
GPU, the vendor's EGL) or ``MUJOCO_GL=osmesa`` (``libosmesa6``) before starting Python. ``RenderError`` says so
when no backend works.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

VIDEO_SUFFIXES = (".gif", ".mp4")


class RenderError(RuntimeError):
    """No OpenGL context could be made (or a video format is unavailable); the message says what to install."""


def render_frames(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    camera: dict[str, float | Sequence[float]],
    width: int = 320,
    height: int = 240,
) -> list[np.ndarray]:
    """(T, nq) joint positions -> T (height, width, 3) uint8 frames seen from a free camera.

    Args:
        model: the env's ``mj_model``.
        qpos: positions per frame.
        camera: ``lookat`` (3,), ``distance``, ``azimuth``, ``elevation`` of an ``MjvCamera``.
        width, height: frame size in pixels.
    """
    data = mujoco.MjData(model)
    free = mujoco.MjvCamera()
    free.lookat[:] = camera["lookat"]
    free.distance, free.azimuth, free.elevation = camera["distance"], camera["azimuth"], camera["elevation"]
    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception as error:  # no GL context
        raise RenderError(
            f"no OpenGL context ({error}); set MUJOCO_GL=egl (libegl1) or MUJOCO_GL=osmesa (libosmesa6)"
        ) from None
    frames = []
    with renderer:
        for q in np.asarray(qpos):
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, free)
            frames.append(renderer.render().copy())
    return frames


def caption(frames: list[np.ndarray], text: str) -> list[np.ndarray]:
    """Frames with ``text`` written on a dark band along their top edge."""
    from PIL import Image, ImageDraw

    out = []
    for frame in frames:
        image = Image.fromarray(frame)
        draw = ImageDraw.Draw(image)
        draw.rectangle((0, 0, image.width, 14), fill=(0, 0, 0))
        draw.text((3, 1), text, fill=(255, 255, 255))
        out.append(np.asarray(image))
    return out


def write_video(frames: list[np.ndarray], path: str | Path, fps: float = 10.0) -> Path:
    """Writes frames as a GIF (Pillow) or an MP4 (matplotlib + the ``ffmpeg`` program), chosen by the suffix."""
    path = Path(path)
    if path.suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"video file {path} must end in one of {', '.join(VIDEO_SUFFIXES)}")
    if not frames:
        raise ValueError("no frames to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(frame) for frame in frames]
        images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
        return path
    if shutil.which("ffmpeg") is None:
        raise RenderError("an .mp4 needs the ffmpeg program on PATH; write a .gif instead")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FFMpegWriter

    height, width = frames[0].shape[:2]
    figure = plt.figure(figsize=(width / 100, height / 100), dpi=100)
    axes = figure.add_axes((0, 0, 1, 1))
    axes.axis("off")
    image = axes.imshow(frames[0])
    writer = FFMpegWriter(fps=fps)
    with writer.saving(figure, str(path), dpi=100):
        for frame in frames:
            image.set_data(frame)
            writer.grab_frame()
    plt.close(figure)
    return path

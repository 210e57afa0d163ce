"""Offscreen rendering of env trajectories (any registered env) to frames, GIF or MP4.

Rendering needs an OpenGL context, which MuJoCo makes with the backend named by ``MUJOCO_GL`` (read when ``mujoco`` is
imported). With ``MUJOCO_GL`` set, or a display to draw on, that choice stands. On a machine with neither (a headless
Linux server, a container) MuJoCo's default (GLFW) needs a display and fails, and by the time anything renders
``mujoco`` has long been imported, so setting the variable then changes nothing. There the renderer makes its own
off-screen context: EGL (packages ``libegl1`` + ``libgl1``; with a GPU, the vendor's EGL), else OSMesa
(``libosmesa6``). ``RenderError`` says in one line what to install or set when none works.
"""

from __future__ import annotations

import os
import platform
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

VIDEO_SUFFIXES = (".gif", ".mp4")


_NO_CONTEXT = (
    "no OpenGL context for rendering: install EGL (Debian/Ubuntu: libegl1 libgl1) or OSMesa (libosmesa6), "
    "or set MUJOCO_GL=egl or MUJOCO_GL=osmesa before starting Python"
)
_HEADLESS_BACKENDS = ("egl", "osmesa")  # MuJoCo's off-screen GL contexts, in the order they are tried


class RenderError(RuntimeError):
    """No OpenGL context could be made (or a video format is unavailable); the message says what to install."""


def headless() -> bool:
    """Whether MuJoCo's own choice of OpenGL cannot work: no ``MUJOCO_GL`` and no display on Linux."""
    has_display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    return platform.system() == "Linux" and not os.environ.get("MUJOCO_GL") and not has_display


def _headless_context(width: int, height: int) -> Any:
    """A current off-screen GL context of MuJoCo's EGL, else OSMesa, module; ``RenderError`` when neither works.
    Importing ``mujoco.egl`` sets ``PYOPENGL_PLATFORM=egl`` unless set; that only matters to PyOpenGL users."""
    errors = []
    for backend in _HEADLESS_BACKENDS:
        try:
            if backend == "egl":
                from mujoco.egl import GLContext
            else:
                from mujoco.osmesa import GLContext
            context = GLContext(width, height)
        except Exception as error:  # a missing library or driver: ImportError, OSError, RuntimeError, GLError
            errors.append(f"{backend}: {str(error).splitlines()[0] if str(error) else type(error).__name__}")
            continue
        context.make_current()
        return context
    raise RenderError(f"{_NO_CONTEXT} ({'; '.join(errors)})")


def _render_with(model: mujoco.MjModel, data: mujoco.MjData, qpos, camera, width: int, height: int):
    """Frames drawn with the GL context that is current, through MuJoCo's scene and render calls."""
    context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
    try:
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, context)
        scene, option = mujoco.MjvScene(model, maxgeom=10_000), mujoco.MjvOption()
        rect = mujoco.MjrRect(0, 0, width, height)
        frames = []
        for q in qpos:
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            mujoco.mjv_updateScene(model, data, option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
            mujoco.mjr_render(rect, scene, context)
            pixels = np.empty((height, width, 3), np.uint8)
            mujoco.mjr_readPixels(pixels, None, rect, context)
            frames.append(np.flipud(pixels).copy())  # OpenGL's rows run bottom-up
        return frames
    finally:
        context.free()


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
    buffer = (model.vis.global_.offwidth, model.vis.global_.offheight)
    if width > buffer[0] or height > buffer[1]:
        raise ValueError(
            f"frames of {width}x{height} exceed the model's off-screen buffer of {buffer[0]}x{buffer[1]}; render "
            "smaller frames or raise <visual><global offwidth=... offheight=.../></visual> in the model"
        )
    data = mujoco.MjData(model)
    free = mujoco.MjvCamera()
    free.lookat[:] = camera["lookat"]
    free.distance, free.azimuth, free.elevation = camera["distance"], camera["azimuth"], camera["elevation"]
    if headless():
        context = _headless_context(width, height)
        try:
            return _render_with(model, data, np.asarray(qpos), free, width, height)
        finally:
            context.free()
    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception as error:  # no GL context
        raise RenderError(f"{_NO_CONTEXT} ({str(error).splitlines()[0]})") from None
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

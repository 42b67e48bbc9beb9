"""Write rendered frames (uint8 ``[H, W, 3]``) to an animated GIF or, if possible, an MP4.

GIF is always available (Pillow). MP4 needs an imageio ffmpeg backend (``imageio-ffmpeg`` or
``av``); without one, asking for ``.mp4`` raises a ``RuntimeError`` that says GIF works.
Files are written atomically: to a temporary file in the target directory, then
``os.replace``, so a reader never sees a half-written video.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from typing import Any

import numpy as np

from hybridmarl.io import grant_umask

__all__ = ["mp4_supported", "write_video"]


def mp4_supported() -> bool:
    """Whether an imageio backend able to write MP4 is importable."""
    for module in ("imageio_ffmpeg", "av"):
        try:
            __import__(module)
        except ImportError:
            continue
        return True
    return False


def _check_frames(frames: Sequence[np.ndarray]) -> list[np.ndarray]:
    if len(frames) == 0:
        raise ValueError("write_video needs at least one frame")
    out = [np.asarray(f) for f in frames]
    shape = out[0].shape
    for i, f in enumerate(out):
        if f.dtype != np.uint8 or f.ndim != 3 or f.shape[-1] != 3:
            raise ValueError(f"frame {i}: expected uint8 [H, W, 3], got {f.dtype} {f.shape}")
        if f.shape != shape:
            raise ValueError(f"frame {i}: shape {f.shape} differs from frame 0's {shape}")
    return out


def write_video(frames: Sequence[np.ndarray], path: str | os.PathLike[str], fps: int = 4) -> str:
    """Write ``frames`` to ``path`` (``.gif``, or ``.mp4`` with an ffmpeg backend).

    Returns the path written. The parent directory is created if needed.
    """
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".gif", ".mp4"):
        raise ValueError(f"unsupported video format {ext!r}: use .gif (or .mp4 with ffmpeg)")
    if ext == ".mp4" and not mp4_supported():
        raise RuntimeError(
            "writing .mp4 needs an imageio ffmpeg backend (imageio-ffmpeg or av), which is not "
            "installed; .gif is supported"
        )
    checked = _check_frames(frames)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=ext, dir=directory)
    os.close(fd)
    try:
        if ext == ".gif":
            from PIL import Image

            images = [Image.fromarray(f) for f in checked]
            images[0].save(
                tmp,
                format="GIF",
                save_all=True,
                append_images=images[1:],
                duration=round(1000 / fps),
                loop=0,
            )
        else:
            import imageio.v2 as imageio

            ims: list[Any] = list(checked)
            imageio.mimwrite(tmp, ims, fps=fps)
        grant_umask(tmp)  # mkstemp makes it 0600; the user's umask decides, as for any file
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return path

"""Recording (the K key): every frame shown while recording goes into a video, and the camera
path beside it, ``NAME.camera.json``: the scene time and the camera (eye, target, up, fov) of each
recorded frame, in order.

The video is an MP4 (H.264, ``VIDEO_FPS`` frames per second) through imageio's ffmpeg plugin
where it is installed (``pip install -e '.[video]'``: imageio and imageio-ffmpeg, which brings
its own ffmpeg); without it the frames go to a folder of PNGs, ``NAME/frame_00000.png``, ...,
which any video tool reads.  A frame whose width or height is odd is padded by one edge pixel
for the video (H.264 wants even sizes); every frame of one recording has the first one's size.
"""

import json
import os
from pathlib import Path

import numpy as np

#: frames per second of the recorded video (a frame shown is a frame of the video)
VIDEO_FPS = 30


def video_writer_available():
    """Whether imageio with its ffmpeg plugin is installed (MP4 out); else PNG sequences."""
    try:
        import imageio.v2  # noqa: F401  # deferred: an optional extra, looked for only when recording starts
        import imageio_ffmpeg  # noqa: F401  # deferred: an optional extra, looked for only when recording starts
    except ImportError:
        return False
    return True


def _next_free(folder, stem, suffix):
    i = 0
    while (folder / f"{stem}_{i:04d}{suffix}").exists() or (folder / f"{stem}_{i:04d}.camera.json").exists():
        i += 1
    return folder / f"{stem}_{i:04d}{suffix}"


class Recorder:
    """One recording into ``folder``: :meth:`add` each frame shown, :meth:`close` at the end."""

    def __init__(self, folder, video=None):
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.video = video_writer_available() if video is None else bool(video)
        self.path = _next_free(folder, "gridrt_rec", ".mp4" if self.video else "")
        self.camera_path = self.path.with_name(self.path.stem + ".camera.json")
        self.frames = 0
        self.size = None
        self.cameras = []
        self._writer = None
        if self.video:
            import imageio.v2 as imageio  # deferred: imageio loads only when a video is recorded

            self._writer = imageio.get_writer(str(self.path), fps=VIDEO_FPS, codec="libx264", quality=8,
                                              macro_block_size=1, pixelformat="yuv420p")
        else:
            self.path.mkdir()

    def add(self, rgb, t, cam):
        """Append the frame ``rgb`` ((H, W, 3) uint8), shown at scene time ``t`` through Camera
        ``cam`` (None: not framed yet)."""
        img = np.ascontiguousarray(rgb[..., :3])
        if self.size is None:
            self.size = img.shape[:2]
        elif img.shape[:2] != self.size:   # the window changed size: the first frame's size
            h, w = self.size
            img = np.ascontiguousarray(np.pad(img[:h, :w], ((0, max(h - img.shape[0], 0)),
                                                            (0, max(w - img.shape[1], 0)), (0, 0)), mode="edge"))
        if self.video:
            h, w = img.shape[:2]
            self._writer.append_data(np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge"))
        else:
            from PIL import Image  # deferred: Pillow loads only when a frame is saved

            Image.fromarray(img).save(self.path / f"frame_{self.frames:05d}.png")
        self.cameras.append({"frame": self.frames, "t": float(t),
                             "camera": None if cam is None else {"eye": list(cam.eye), "target": list(cam.target),
                                                                 "up": list(cam.up), "fov": float(cam.fov)}})
        self.frames += 1

    def close(self):
        """Finish the video and write the camera path; returns the video's (or folder's) path."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        tmp = self.camera_path.with_name(self.camera_path.name + ".tmp")
        tmp.write_text(json.dumps({"fps": VIDEO_FPS, "frames": self.cameras}, indent=1) + "\n")
        os.replace(tmp, self.camera_path)
        return self.path

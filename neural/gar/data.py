"""Real training photos of the GAR and its auxiliary networks, aligned to the synthetic faces'
framing.

:class:`AlignedImageFolder`: any folder of face photos (FFHQ-style), each aligned by a
similarity warp of its 68 landmarks (a ``.pts`` file beside the image, or dlib's detector) to
:func:`neural.faces.renders.template` — the landmarks of the mean face as the synthetic camera
sees it, so that real and synthetic images (:class:`neural.faces.renders.SyntheticFaces`) share
one framing. :func:`alignment`, :func:`aligned_camera`, :func:`align_image`, :func:`warp_image`
are its steps, also used by the real-photo pack (:mod:`neural.gar.build_real`).

Images are float tensors (B, 3, R, R) in [-1, 1]; landmarks are pixels (x right, y down,
0-based pixel centres).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from morphable.errors import InputError
from morphable.metrics import umeyama

from ..faces.renders import template

__all__ = ["AlignedImageFolder", "alignment", "aligned_camera", "align_image", "warp_image",
           "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".bmp", ".webp")


# --- real images ----------------------------------------------------------------------
def alignment(landmarks, resolution: int = 64, model: str = "sfm") -> np.ndarray:
    """The similarity that :func:`align_image` warps a photo by: (68, 2) 0-based pixels ->
    (2, 3) ``A`` with ``crop_px = A[:, :2] @ photo_px + A[:, 2]`` (a scaled rotation and a
    shift, least squares onto :func:`template`)."""
    scale, R, t = umeyama(landmarks, template(resolution, model))
    return np.hstack([scale * R, t[:, None]])


def aligned_camera(camera, A, resolution: int):
    """The camera that sees what ``camera`` sees, in the crop a photo is warped to by the
    similarity ``A`` (2, 3) of :func:`alignment`: the image-plane rotation becomes a roll
    about the camera's axis, the scale multiplies the camera's, the shift its principal point
    (:func:`morphable.refinement.crop.crop_camera` is the case without rotation)."""
    import dataclasses

    A = np.asarray(A, np.float64)
    s = float(np.sqrt(abs(np.linalg.det(A[:, :2]))))
    # pixel y points down, the camera's y up: the same rotation, conjugated by the flip
    flip = np.diag([1.0, -1.0])
    Q = np.eye(3)
    Q[:2, :2] = flip @ (A[:, :2] / s) @ flip
    return dataclasses.replace(camera, rotation=Q @ camera.rotation, translation=Q @ camera.translation,
                               scale=camera.scale * s, focal=camera.focal * s,
                               image_size=(resolution, resolution),
                               principal=A[:, :2] @ camera.principal + A[:, 2])


def align_image(image, landmarks, resolution: int = 64, model: str = "sfm") -> np.ndarray:
    """Warp a photo so that its 68 landmarks (pixels) match :func:`template`.

    image : (H, W, 3) uint8 or PIL image; landmarks : (68, 2) 0-based pixels ->
    (resolution, resolution, 3) uint8.
    """
    return warp_image(image, alignment(landmarks, resolution, model), resolution)


def warp_image(image, A, resolution: int) -> np.ndarray:
    """(H, W, 3) uint8 or PIL image -> (resolution, resolution, 3) uint8 by the similarity
    ``A`` (2, 3) of :func:`alignment` (bicubic). Where the crop leaves the photo it shows
    FFHQ's mirrored, blurred and faded background
    (:func:`morphable.refinement.pad_like_ffhq`), not black. A photo shrunk by 2 or more is
    first box-filtered by the whole factor, so that the bicubic warp does not alias."""
    from PIL import Image

    from morphable.refinement import pad_like_ffhq

    img = image if isinstance(image, Image.Image) else Image.fromarray(np.asarray(image))
    img = img.convert("RGB")
    A = np.asarray(A, np.float64)
    f = int(1.0 / np.sqrt(abs(np.linalg.det(A[:, :2]))))
    if f >= 2:
        # reduced pixel q covers photo pixels f q .. f q + f - 1: its centre is f q + (f - 1) / 2
        img = img.reduce(f)
        A = np.hstack([A[:, :2] * f, (A[:, :2] @ np.full(2, (f - 1) / 2) + A[:, 2])[:, None]])
    # the crop's corners in the photo, pixel-edge coordinates (pixel centres are integers)
    corners = np.array([[-0.5, -0.5], [resolution - 0.5, -0.5], [-0.5, resolution - 0.5],
                        [resolution - 0.5, resolution - 0.5]])
    quad = (corners - A[:, 2]) @ np.linalg.inv(A[:, :2]).T + 0.5
    padded, (dx, dy) = pad_like_ffhq(np.asarray(img), (*quad.min(0), *quad.max(0)))
    if dx or dy:
        img = Image.fromarray(padded)
        A = np.hstack([A[:, :2], (A[:, 2] - A[:, :2] @ np.array([dx, dy], np.float64))[:, None]])
    # PIL wants the inverse map (output pixel -> input pixel) in pixel-corner coordinates;
    # our pixel centres are integers, PIL's are at +0.5
    inv = np.linalg.inv(np.vstack([A, [0, 0, 1]]))
    shift = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1]])
    M = np.linalg.inv(shift) @ inv @ shift
    out = img.transform((resolution, resolution), Image.Transform.AFFINE, M[:2].ravel().tolist(),
                        resample=Image.Resampling.BICUBIC)
    return np.asarray(out)


class AlignedImageFolder(torch.utils.data.Dataset):
    """Face photos of a folder, aligned to :func:`template`, as (3, R, R) tensors in [-1, 1].

    Landmarks come from ``<image>.pts`` beside each image (iBUG format, 1-based) when it
    exists, else from dlib's 68-point detector (:func:`morphable.detection.detect_landmarks`);
    an image without a face is replaced by the next one that has one. With ``aligned=True`` the images are taken as already aligned (e.g.
    the output of :func:`prepare_folder`) and only resized.
    """

    def __init__(self, root, resolution: int = 64, aligned: bool = False, model: str = "sfm"):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"{self.root}: image folder not found")
        self.files = sorted(p for p in self.root.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise InputError(f"{self.root}: no images ({', '.join(IMAGE_SUFFIXES)})")
        self.resolution, self.aligned, self.model = int(resolution), aligned, model

    def __len__(self):
        return len(self.files)

    def load(self, i: int) -> np.ndarray | None:
        """Aligned (R, R, 3) uint8 image ``i``, or None when no face is found."""
        from PIL import Image

        path = self.files[i]
        try:
            img = Image.open(path).convert("RGB")
        except OSError as e:
            raise InputError(f"{path}: cannot read image ({e})") from None
        R = self.resolution
        if self.aligned:
            return np.asarray(img.resize((R, R), Image.Resampling.LANCZOS))
        pts = path.with_suffix(".pts")
        if pts.is_file():
            from morphable.io.landmark_files import read_pts

            lm = read_pts(pts)
        else:
            from morphable.errors import FitError
            from morphable.detection import detect_landmarks

            try:
                lm = detect_landmarks(np.asarray(img), landmark_detector="dlib")
            except FitError:
                return None
        return align_image(img, lm, R, self.model)

    def __getitem__(self, i):
        # no face: fall back on the next image so that a DataLoader never sees None
        for k in range(len(self)):
            img = self.load((i + k) % len(self))
            if img is not None:
                return torch.as_tensor(img.transpose(2, 0, 1).copy(), dtype=torch.float32) / 127.5 - 1
        raise InputError(f"{self.root}: no face found in any image")


def prepare_folder(src, dst, resolution: int = 256, model: str = "sfm") -> int:
    """Align every face photo of ``src`` once and write PNGs to ``dst``; returns the count
    written. Train on ``dst`` with ``--images dst --aligned``."""
    from PIL import Image

    from morphable.io.atomic import atomic_path

    data = AlignedImageFolder(src, resolution, model=model)
    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    n = 0
    for i in range(len(data)):
        img = data.load(i)
        if img is None:
            continue
        with atomic_path(dst / f"{data.files[i].stem}.png") as tmp:
            Image.fromarray(img).save(tmp, format="PNG")
        n += 1
    return n

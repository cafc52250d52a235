"""Frame pre-processing shared by training and the runtime (NumPy/OpenCV, no torch).

- :func:`center_crop_resize`: centre crop then resize, with the intrinsics updated to match.
- :func:`prepare_network_input`: the whole chain a network sees (crop, resize, the scope's
  border filled from the tissue, inpainting);
  training (:mod:`datamodules.base`) and the ONNX runtime (:mod:`c3f_slam.models`) both call it.
- :func:`on_grid` / :func:`fill_outside`: a frame-grid mask on a network grid, and the pixels
  outside a mask filled from the inside (the scope's border, :mod:`c3f_slam.frames.tissue`).
- :func:`specular_mask` / :func:`inpaint_specular` (docs/design.md, Pre-processing): the
  specular highlights are the pixels whose YUV luma Y exceeds 0.9 of full range, dilated with a
  13-px kernel; they are inpainted in the input (OpenCV Telea) and excluded from the losses.
"""

from __future__ import annotations

import cv2
import numpy as np

from c3f_slam.camera.intrinsics import PinholeCamera

IMAGENET_MEAN = (0.485, 0.456, 0.406)  # RGB in [0, 1]; the nets normalise inside (and in their ONNX graphs)
IMAGENET_STD = (0.229, 0.224, 0.225)
SPECULAR_THRESHOLD = 0.9
SPECULAR_DILATION_PX = 13


def center_crop_resize(
    image: np.ndarray,
    camera: PinholeCamera,
    crop: tuple[int, int] | None,
    size: tuple[int, int] | None,
    interpolation: int = cv2.INTER_AREA,
) -> tuple[np.ndarray, PinholeCamera]:
    """Centre-crop to ``crop`` = (width, height), then resize to ``size`` = (width, height).

    Either step is skipped when its argument is None. Returns the image and the matching
    intrinsics. Use ``cv2.INTER_NEAREST`` for depth maps so that depths across an edge are
    never averaged.
    """
    camera.check_image(image.shape, "frame")
    if crop is not None:
        x0, y0, w, h = camera.center_crop_box(*crop)
        image = image[y0 : y0 + h, x0 : x0 + w]
        camera = camera.crop(x0, y0, w, h)
    if size is not None and tuple(size) != (camera.width, camera.height):
        image = cv2.resize(image, tuple(size), interpolation=interpolation)
        camera = camera.resize(*size)
    return image, camera


def specular_mask(
    rgb: np.ndarray,
    threshold: float = SPECULAR_THRESHOLD,
    dilation_px: int = SPECULAR_DILATION_PX,
) -> np.ndarray:
    """(H, W) bool mask of specular highlights of an (H, W, 3) uint8 RGB frame.

    Y (BT.601 luma, full range) > ``threshold`` * 255, dilated by an elliptical
    ``dilation_px`` x ``dilation_px`` kernel.
    """
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"specular_mask expects (H, W, 3) uint8 RGB, got {rgb.dtype} {rgb.shape}")
    y = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV)[..., 0]
    mask = (y > threshold * 255.0).astype(np.uint8)
    if dilation_px > 1 and mask.any():
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (dilation_px, dilation_px))
        mask = cv2.dilate(mask, kernel)
    return mask.astype(bool)


def inpaint_specular(rgb: np.ndarray, mask: np.ndarray, radius: int = 3) -> np.ndarray:
    """Fill the masked pixels of an (H, W, 3) uint8 image from their surroundings (Telea)."""
    if not mask.any():
        return rgb
    return cv2.inpaint(rgb, mask.astype(np.uint8), radius, cv2.INPAINT_TELEA)


def on_grid(mask: np.ndarray, box: tuple[int, int, int, int], size: tuple[int, int]) -> np.ndarray:
    """A frame-grid mask cropped to ``box`` = (x0, y0, w, h) and resized to ``size`` = (w, h):
    a grid pixel is tissue when at least half of the frame pixels it covers are."""
    x0, y0, w, h = box
    crop = mask[y0:y0 + h, x0:x0 + w].astype(np.float32)
    if (w, h) == tuple(size):
        return crop > 0.5
    return cv2.resize(crop, tuple(size), interpolation=cv2.INTER_AREA) >= 0.5


def fill_outside(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 ``rgb`` with the pixels outside ``mask`` replaced by a smooth continuation
    of the tissue (pull-push: masked averages down an image pyramid, then filled back up), so a
    network sees no black border. Pixels inside the mask are unchanged."""
    if mask.all():
        return rgb
    levels: list[tuple[np.ndarray, np.ndarray]] = []
    img = rgb.astype(np.float32) * mask[..., None]
    w = mask.astype(np.float32)
    while True:
        levels.append((img, w))
        if min(w.shape) <= 2:
            break
        img, w = cv2.pyrDown(img), cv2.pyrDown(w)
    img, w = levels[-1]
    filled = np.where(w[..., None] > 1e-6, img / np.maximum(w[..., None], 1e-6),
                      img.sum(axis=(0, 1)) / max(float(w.sum()), 1e-6))
    for img, w in reversed(levels[:-1]):
        up = cv2.pyrUp(filled, dstsize=(w.shape[1], w.shape[0]))
        own = img / np.maximum(w[..., None], 1e-6)
        alpha = np.clip(w, 0.0, 1.0)[..., None]
        filled = alpha * own + (1.0 - alpha) * up
    out = rgb.copy()
    out[~mask] = np.clip(np.rint(filled[~mask]), 0, 255).astype(np.uint8)
    return out


def prepare_network_input(
    rgb: np.ndarray,
    camera: PinholeCamera,
    *,
    crop: tuple[int, int] | None,
    size: tuple[int, int] | None,
    specular: bool = True,
    specular_threshold: float = SPECULAR_THRESHOLD,
    specular_dilation_px: int = SPECULAR_DILATION_PX,
    tissue: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, PinholeCamera]:
    """What a network sees of an (H, W, 3) uint8 RGB frame.

    Centre crop ``crop`` = (width, height), resize to ``size`` = (width, height)
    (:func:`center_crop_resize`); with ``tissue`` ((H, W) bool, True = tissue: the frame's
    :class:`c3f_slam.frames.tissue.TissueMask`), the pixels outside it filled by a smooth continuation of
    the tissue (:func:`fill_outside`), so the black border does not bias the
    prediction; then, with ``specular``, the specular mask of the resized frame
    (``specular_threshold``, ``specular_dilation_px``) and Telea inpainting of its pixels.
    Returns (uint8 RGB, (h, w) bool specular mask, intrinsics of the returned image).
    """
    box = camera.center_crop_box(*crop) if crop is not None else (0, 0, camera.width, camera.height)
    rgb, cam = center_crop_resize(rgb, camera, crop, size)
    if tissue is not None and not tissue.all():
        rgb = fill_outside(rgb, on_grid(tissue, box, (cam.width, cam.height)))
    if specular:
        mask = specular_mask(rgb, specular_threshold, specular_dilation_px)
        rgb = inpaint_specular(rgb, mask)
    else:
        mask = np.zeros(rgb.shape[:2], bool)
    return rgb, mask, cam

"""Active contours against scikit-image."""

from __future__ import annotations

from typing import Any

import numpy as np

from peer_cases._common import _compare


def snake_cases(repeats: int) -> list[dict[str, Any]]:
    """Issue 16: one silhouette contour on the disparity-filtered gradient of a cluttered
    480x360 view (seed 2 of the clutter scene), started 3 pixels outside the true outline:
    elastocap's active contour (resampled, 150 iterations at most) vs
    skimage.segmentation.active_contour on the same attraction image (``w_line=1``,
    ``w_edge=0``: both climb it), same start, same iteration cap. Also reports each one's IoU
    with the true mask."""
    import cv2
    from skimage.segmentation import active_contour as skimage_contour

    from elastocap.silhouettes.gradient import filtered_gradient
    from elastocap.silhouettes.model_based import SNAKE_DEFAULTS
    from elastocap.silhouettes.snake import active_contour, mask_contours, polygon_mask
    from elastocap.synth.clutter import ClutterScene

    scene = ClutterScene(2, frames=300)
    frame = scene.frame(20)
    name = scene.rig.names[0]
    truth = frame.masks[name]
    attraction, _ = filtered_gradient(frame.images[name], frame.disparity_masks[name])
    start = mask_contours(cv2.dilate(truth.astype(np.uint8), np.ones((7, 7), np.uint8)))[0]
    start = start[:: max(1, len(start) // 300)]
    ours = lambda: active_contour(attraction, start, **SNAKE_DEFAULTS)  # noqa: E731
    peer = lambda: skimage_contour(attraction, start[:, ::-1], alpha=0.01, beta=0.02, w_line=1.0, w_edge=0.0, gamma=0.1, max_num_iter=150)  # noqa: E731
    row = _compare("snake_480x360_view", len(start), ours, "skimage.segmentation.active_contour", peer, repeats)

    def iou(mask: np.ndarray) -> float:
        return float((mask & truth).sum() / (mask | truth).sum())

    result = ours()
    row["ours_iou"] = round(iou(polygon_mask([result.points], truth.shape)), 4) if result.points is not None else 0.0
    row["peer_iou"] = round(iou(polygon_mask([peer()[:, ::-1]], truth.shape)), 4)
    return [row]

"""Model-based silhouettes in clutter (issue 16) on a short piece of the synthetic
cluttered capture: the loop (snake -> body fit -> model -> snake) beats a snake that only
follows its previous result; a view without disparity still gets a silhouette; the first
frame needs the cameras to agree on something; ``elastocap silhouettes`` writes masks that
``elastocap hull`` then uses."""

from __future__ import annotations

import numpy as np
import pytest

from elastocap import InvalidInputError
from elastocap.pipeline.cli import main
from elastocap.silhouettes.gradient import filtered_gradient
from elastocap.silhouettes.model_based import SNAKE_DEFAULTS, SilhouetteTracker, agreed_silhouettes
from elastocap.silhouettes.snake import snake_silhouette
from elastocap.synth.clutter import ClutterScene, write_clutter_capture

FRAMES = 4


@pytest.fixture(scope="module")
def piece():
    scene = ClutterScene(4, cameras=5, size=(320, 240), frames=60)
    return scene, [scene.frame(f) for f in range(FRAMES)]


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def test_the_loop_beats_the_snake_alone(piece) -> None:
    scene, frames = piece
    names = scene.rig.names
    tracker = SilhouetteTracker(scene.rig)
    loop, alone = [], []
    chain = agreed_silhouettes(scene.rig, frames[0].disparity_masks)
    for f, frame in enumerate(frames):
        # an empty disparity in one view of frame 2: its gradient is unfiltered
        disparity = dict(frame.disparity_masks)
        if f == 2:
            disparity[names[0]] = np.zeros_like(disparity[names[0]])
        masks = tracker.step(frame.images, disparity_masks=disparity, points=frame.points)
        assert set(masks) == set(names)
        loop.append([iou(masks[n], frame.masks[n]) for n in names])
        snaked = {}
        for n in names:
            attraction, _ = filtered_gradient(frame.images[n], disparity[n])
            mask, _ = snake_silhouette(attraction, chain[n], **SNAKE_DEFAULTS)
            snaked[n] = chain[n] if mask is None else mask
        chain = snaked
        alone.append([iou(chain[n], frame.masks[n]) for n in names])
    loop_iou, alone_iou = np.array(loop), np.array(alone)
    assert loop_iou[1:].mean() > alone_iou[1:].mean()
    assert np.median(loop_iou) > 0.7
    assert loop_iou[2, 0] > 0.5
    # Each view's learned background, taught by the loop outside its fitted model, knows the
    # background under the scene's light and has not learned the figure as background.
    last = frames[-1]
    for n in names:
        support = ~tracker.model_masks[n]
        distance = tracker.backgrounds[n].distance(last.images[n], support)
        known = np.isfinite(distance)
        assert (known & ~last.masks[n]).mean() > 0.3
        assert np.median(distance[known & ~last.masks[n]]) < 10.0
        assert (known & last.masks[n] & (distance < 15.0)).sum() < 0.02 * last.masks[n].sum()


def test_the_first_frame_needs_agreement(piece) -> None:
    scene, frames = piece
    empty = {n: np.zeros_like(m) for n, m in frames[0].disparity_masks.items()}
    with pytest.raises(InvalidInputError, match="agree on nothing"):
        SilhouetteTracker(scene.rig).step(frames[0].images, disparity_masks=empty)
    with pytest.raises(InvalidInputError, match="disparity mask for every camera"):
        SilhouetteTracker(scene.rig).step(frames[0].images)
    with pytest.raises(InvalidInputError, match="images lack"):
        SilhouetteTracker(scene.rig).step({})


def test_silhouettes_command_writes_masks_the_hull_uses(tmp_path) -> None:
    scene = ClutterScene(5, cameras=4, size=(240, 180), frames=2)
    capture, out = tmp_path / "capture", tmp_path / "out"
    write_clutter_capture(scene, capture, out, range(2))
    assert main(["silhouettes", str(capture), "--out", str(out), "--quiet"]) == 0
    for name in scene.rig.names:
        assert sorted(p.name for p in (out / "masks" / name).glob("*.png")) == ["000000.png", "000001.png"]
    assert main(["hull", str(capture), "--out", str(out), "--resolution", "48", "--quiet"]) == 0
    assert (out / "hull" / "000001.npz").exists()
    # a second run finds the masks and does nothing
    assert main(["silhouettes", str(capture), "--out", str(out), "--quiet"]) == 0

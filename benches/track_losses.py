"""Why tracks are not tracked through their visibility (issue 15's "through" figure).

For every measured track of ``OUT/tracks`` (written by ``track_points(capture, out=OUT)``
on a textured synthetic capture) that is not tracked through its visibility, its first
loss: the frame after its seeding where the truth is seen by two cameras and the track has
no position. Prints one JSON line of counts (the circumstance, the point flag, the
per-view flags and silhouette-edge distances of the views that were held and are still
visible, how long other cameras had seen a point whose held views turned invisible, how
long a point that came back had been gone, losses per frame), then the table
circumstance x point flag.

    python benches/track_losses.py CAPTURE OUT
"""
import collections
import json
import sys

import cv2
import numpy as np
from scipy.spatial import cKDTree
from elastocap import Capture
from elastocap.synth.textured import load_textured_truth
from elastocap.tracking import load_tracks
from elastocap.tracking.accuracy import track_accuracy
from elastocap.tracking.flags import TrackFlag
folder, out = sys.argv[1], sys.argv[2]
cap = Capture.open(folder)
truth = load_textured_truth(folder)
tr = load_tracks(out)
f, n = tr.flags.shape
vis, pos, mat = truth.visible[:f], truth.positions[:f], truth.material[:f]
acc = track_accuracy(tr, cap.rig.cameras, pos, vis, truth.part, material=mat)
tracked = tr.flags == 0
first = np.where(tracked.any(axis=0), np.argmax(tracked, axis=0), -1)
# seen (F, C, N) as track_accuracy computes it (the 8 truth neighbours all visible).
c = len(cap.rig.cameras)
seen = np.zeros((f, c, n), bool)
usable, part_ = mat.all(axis=0), truth.part
for s in np.unique(first[first >= 0]):
    rows = np.flatnonzero(first == s)
    x0 = tr.positions[s, rows]
    _, nearest = cKDTree(pos[s]).query(x0, k=1)
    near = np.zeros((rows.size, 8), np.int64)
    for p in np.unique(part_[nearest]):
        on = np.flatnonzero((part_ == p) & usable)
        sel = part_[nearest] == p
        _, idx = cKDTree(pos[s, on]).query(x0[sel], k=8)
        near[sel] = on[idx]
    for t in range(s, f):
        seen[t][:, rows] = vis[t][:, near].all(axis=2)
assert (seen.sum(axis=1) >= 2)[acc.expected].all() and ((seen.sum(axis=1) >= 2) == acc.expected).all()
views = np.isfinite(tr.views[..., 0])  # (F, N, C)
f2d = np.zeros((f, n, c), np.uint8)
for i, fr in enumerate(tr.frames):
    d = np.load(f"{out}/tracks/{int(fr):06d}.npz")
    cols = np.searchsorted(tr.ids, d["ids"])
    f2d[i, cols] = d["flags2d"]
names = cap.rig.names
edge = {}
def dist(t, k):
    if (t, k) not in edge:
        m = cap.mask(names[k], int(tr.frames[t])).astype(np.uint8)
        edge[t, k] = cv2.distanceTransform(m, cv2.DIST_L2, 3)
    return edge[t, k]
rows = np.flatnonzero(acc.measured & ~acc.through)
table, pflag, vflag, circ = (collections.Counter() for _ in range(4))
near_edge, chance, gap, lost_while, lossframe = (collections.Counter() for _ in range(5))
for p in rows:
    bad = np.flatnonzero(acc.expected[:, p] & ~tracked[:, p] & (np.arange(f) > first[p]))
    t = int(bad[0])
    flag = TrackFlag(int(tr.flags[t, p])).name
    if not tracked[t - 1, p]:
        what = "came back (not tracked on the frame before)"
        held = []
        last = np.flatnonzero(tracked[:t, p])[-1]
        g = t - 1 - last
        gap["1" if g == 1 else "2-4" if g < 5 else "5-14" if g < 15 else ">=15"] += 1
        # Was it expected (seen by 2 cameras) on the frame it was lost?
        lost_while["expected when lost" if acc.expected[last + 1, p] else "not expected when lost"] += 1
    else:
        held = np.flatnonzero(views[t - 1, p])
        gone = [k for k in held if not seen[t, k, p]]
        age = t - first[p]
        if len(gone):
            what = f"a held view turned invisible ({len(gone)} of {len(held)})"
            # Cameras that see it at t, not held: since how many frames did they see it
            # while the track held its views (the re-acquisition's chance)?
            others = seen[t, :, p] & ~views[t - 1, p]
            window = 0
            while t - 1 - window >= first[p] and tracked[t - 1 - window, p] and (seen[t - 1 - window, :, p] & others).any():
                window += 1
            chance["0" if window == 0 else "1" if window == 1 else "2-4" if window < 5 else ">=5"] += 1
        elif age == 1:
            what = "first step after seeding, views still visible"
        else:
            what = "views still visible"
        for k in held:
            if seen[t, k, p]:
                vflag[TrackFlag(int(f2d[t, p, k])).name] += 1
                u, v = tr.views[t - 1, p, k]
                dd = dist(t - 1, k)[int(round(v)), int(round(u))]
                near_edge["<8 px" if dd < 8 else "8-12 px" if dd < 12 else ">=12 px"] += 1
    table[what, flag] += 1
    pflag[flag] += 1
    circ[what] += 1
    lossframe[t] += 1
print(json.dumps(dict(measured=int(acc.measured.sum()), not_through=int(rows.size),
    by_circumstance=circ.most_common(), by_point_flag=pflag.most_common(),
    still_visible_view_flags=vflag.most_common(), still_visible_views_edge=near_edge.most_common(), handover_frames_others_saw_it=chance.most_common(), came_back_gap=gap.most_common(), came_back_lost=lost_while.most_common(),
    loss_frames=sorted(lossframe.items())), indent=None))
for (what, flag), k in sorted(table.items(), key=lambda x: -x[1]):
    print(f"{k:5d}  {what:55s} {flag}")

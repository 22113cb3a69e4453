"""LSM accuracy tables of issue 14 (benches/README, section "LSM on faint texture"); not a
peer case, a script: ``python benches/peer_cases/lsm_accuracy.py {faint,sizes} [--seeds A B]``.

faint: normalised variance of the matched centre on procedural texture of contrast 4-35 grey
levels at noise 2, started at the true map, sizes 11 and 21 (tuned on seeds 0-199).
sizes: the warps of tests/test_lsm.py from 2 px off, sizes 11/15/21, procedural and temple
textures (held-out seeds 1000-1399), with the Cramer-Rao bound of the centre at size 11:
``sigma^2 (1 + gain^2) (J^T J)^-1`` with ``J`` from the noise-free texture's gradients (the
texture known: a bound for any unbiased estimator, which must also estimate it).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
import test_lsm as T  # noqa: E402

from elastocap.stereo import MatchStatus  # noqa: E402


def faint(seeds: range) -> None:
    print("| contrast | size | converged | RMS per axis | normalised variance (mean / median) |")
    for contrast in [4, 8, 15, 35]:
        for size in [11, 21]:
            errors, chi2, status = [], [], []
            for seed in seeds:
                rng = np.random.default_rng(seed)
                template, images, truth, _ = T.scene(T.procedural(rng, contrast), rng, *T.warp(rng))
                m = T._match(template, images, truth, size=size, min_texture=0.0)
                status.append(int(m.status[0, 0]))
                if m.status[0, 0] == MatchStatus.CONVERGED:
                    e, c = T._chi2(m, truth)
                    errors.append(e)
                    chi2.append(c)
            e, c = np.array(errors), np.array(chi2)
            print(f"| {contrast} | {size} | {np.mean(np.array(status) == 0):.1%} | {np.sqrt(np.mean(e**2)):.4f} px "
                  f"| {c.mean() / 2:.2f} / {np.median(c) / 1.386:.2f} |", flush=True)


def sizes(seeds: range) -> None:
    print("| texture | size | converged | RMS 2-D / per axis | median 2-D | normalised variance | gross > 0.5 px; "
          "without: RMS 2-D / per axis, normalised variance | Cramer-Rao RMS 2-D / per axis |")
    for kind in ["procedural", "temple"]:
        for size in [11, 15, 21]:
            errors, chi2, status, bound = [], [], [], []
            for seed in seeds:
                rng = np.random.default_rng(seed)
                texture = T.procedural(rng) if kind == "procedural" else T.temple(rng)
                w = T.warp(rng)
                template, images, truth, start = T.scene(texture, rng, *w)
                m = T._match(template, images, start, size=size)
                status.append(int(m.status[0, 0]))
                if m.status[0, 0] == MatchStatus.CONVERGED:
                    e, c = T._chi2(m, truth)
                    errors.append(e)
                    chi2.append(c)
                    if size == 11:
                        bound.append(np.trace(T.cramer_rao(texture, truth, w[4], size)))
            e, c = np.array(errors), np.array(chi2)
            ok = np.linalg.norm(e, axis=1) <= 0.5
            b = np.array(bound)
            crb = f"{np.sqrt(b.mean()):.4f} / {np.sqrt(b.mean() / 2):.4f} px" if len(b) else "-"
            print(f"| {kind} | {size} | {np.mean(np.array(status) == 0):.1%} | {np.sqrt(np.mean(np.sum(e**2, 1))):.4f} / "
                  f"{np.sqrt(np.mean(e**2)):.4f} px | {np.median(np.linalg.norm(e, axis=1)):.3f} px | {c.mean() / 2:.2f} | "
                  f"{int((~ok).sum())}; {np.sqrt(np.mean(np.sum(e[ok] ** 2, 1))):.4f} / {np.sqrt(np.mean(e[ok] ** 2)):.4f} px, "
                  f"{c[ok].mean() / 2:.2f} | {crb} |", flush=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("table", choices=["faint", "sizes"])
    parser.add_argument("--seeds", type=int, nargs=2, default=None, help="first and last + 1")
    args = parser.parse_args()
    default = (0, 200) if args.table == "faint" else (1000, 1400)
    chosen = range(*(args.seeds or default))
    (faint if args.table == "faint" else sizes)(chosen)

"""How much an edge model's reading of real frames depends on its simulated draw: the spread
between the members of a multi-draw model (``tactip sim2real --task edge --draws K``), with no
label (docs/sim2real_log.md, "The component search, its loss, and the edge models averaged over
simulated draws").

    python benchmarks/draw_spread.py RUN_DIR=REAL_DIR [RUN_DIR=REAL_DIR ...] [--labels]

The run's saved model (``RUN_DIR/model.json``) averages members fitted on K draws
(``fitted_on.bagged.draws``; the members of draw j are consecutive). Each draw's members alone
read the real folder's frames (the run's cached tracked points); printed:

- the mean absolute difference (an angle's wrapped) between every two single draws' readings:
  what one draw's model would change on the same frames;
- with K >= 4 the same between the two halves of every split of the draws into two disjoint
  halves (the mean over the splits): what a K/2-draw model would change. For independent draws
  it is the single draws' figure over sqrt(K/2);
- with ``--labels``: each single draw's, each half's and the whole model's MAE against the
  folder's labels (the score the spread moves).

Nothing is fitted or simulated.
"""

from __future__ import annotations

import copy
import itertools
import sys
from pathlib import Path

import numpy as np

from tactip_lab.fitting.field_model import TARGETS, load_field_model, target_scores


def draw_groups(model) -> list[list]:
    """The model's members grouped by simulated draw: K lists of models (the model itself,
    without its members, first in draw 0's)."""
    seeds = model.fitted_on.get("bagged", {}).get("draws") or [None]
    head = copy.copy(model)
    head.members = []
    every = [head, *model.members]
    if len(every) % len(seeds):
        raise ValueError(f"{len(every)} members do not split into {len(seeds)} draws")
    per = len(every) // len(seeds)
    return [every[j * per:(j + 1) * per] for j in range(len(seeds))]


def ensemble(models: list):
    """One model averaging ``models`` (the first carries the others as members)."""
    m = copy.copy(models[0])
    m.members = list(models[1:])
    return m


def difference(a: np.ndarray, b: np.ndarray, targets: list[str]) -> list[float]:
    """Per target the mean absolute difference of two readings (wrapped for an angle): the
    MAE of one against the other (:func:`~tactip_lab.fitting.field_model.target_scores`)."""
    s = target_scores(a, b, targets)
    return [s[t]["mae"] for t in targets]


def halves(k: int) -> list[tuple[tuple[int, ...], tuple[int, ...]]]:
    """Every split of draws 0..k-1 into two disjoint halves (each split once)."""
    out = []
    for first in itertools.combinations(range(k), k // 2):
        if 0 in first:
            out.append((first, tuple(j for j in range(k) if j not in first)))
    return out


def report(run: Path, real: Path, labels: bool) -> None:
    from tactip_lab.real.task_run import folder_columns

    model = load_field_model(run / "model.json")
    targets = model.targets
    z = np.load(run / f"real_{real.name}_points.npz")
    rest, pts = z["rest"], z["pts"]
    groups = draw_groups(model)
    k = len(groups)
    print(f"{run} on {real}: {k} draws of {len(groups[0])} members, {len(pts)} frames")
    if k < 2:
        print("  one draw: nothing to compare")
        return
    reads = [ensemble(g).predict_points(rest, pts) for g in groups]
    units = [TARGETS[t]["unit"] for t in targets]
    pairs = [difference(reads[a], reads[b], targets)
             for a, b in itertools.combinations(range(k), 2)]
    fmt = ", ".join(f"{t} {{:.2f}} {u}" for t, u in zip(targets, units, strict=True))
    print("  single draws, mean over pairs: " + fmt.format(*np.mean(pairs, axis=0)))
    split = halves(k) if k >= 4 else []
    half_reads = []
    for a, b in split:
        ra = ensemble([m for j in a for m in groups[j]]).predict_points(rest, pts)
        rb = ensemble([m for j in b for m in groups[j]]).predict_points(rest, pts)
        half_reads.append((ra, rb, difference(ra, rb, targets)))
    if split:
        d = np.mean([h[2] for h in half_reads], axis=0)
        print(f"  halves of {k // 2} draws, mean over {len(split)} splits: " + fmt.format(*d)
              + "  (independent draws: " + fmt.format(
                  *(np.mean(pairs, axis=0) / np.sqrt(k / 2))) + ")")
    if not labels:
        return
    cols = folder_columns(real)
    y = np.stack([cols[t] for t in targets], axis=1)

    def mae(p):
        s = target_scores(y, p, targets)
        return fmt.format(*[s[t]["mae"] for t in targets])

    for j, r in enumerate(reads):
        print(f"  draw {j} alone: MAE " + mae(r))
    for (a, b), (ra, rb, _) in zip(split, half_reads, strict=True):
        print(f"  draws {a}: MAE {mae(ra)};  draws {b}: MAE {mae(rb)}")
    print("  the whole model: MAE " + mae(model.predict_points(rest, pts)))


def main(argv: list[str]) -> int:
    if not argv or any(a in ("-h", "--help") for a in argv):
        print(__doc__)
        return 0 if argv else 2
    labels = "--labels" in argv
    for pair in (a for a in argv if a != "--labels"):
        if "=" not in pair:
            print(f"expected RUN_DIR=REAL_DIR, got {pair!r}", file=sys.stderr)
            return 2
        run, real = (Path(p) for p in pair.split("=", 1))
        report(run, real, labels)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

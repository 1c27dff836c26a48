"""Folds that judge a model where it was not fitted: by file, placement or workspace region.

Random folds of one recording hold out rows whose neighbours were fitted: they reward a
model that interpolates well, not one that carries to another session, placement or part
of the workspace, which is what a calibration is used for.  :func:`group_folds` splits the
training data by the largest structure they have, in this order:

1. **files** (leave one file out) when there are several training files: a held-out
   file's own parameters (instrument frame, marker, probe) are registered on it with the
   robot fixed, the held-out protocol of another set-up
   (:func:`~kincal.identify.validation.validate`'s ``register``);
2. **placements** (leave one placement out): an artifact file's placements (the sockets of
   a held-out placement are fitted with the robot fixed);
3. **workspace regions**: the joint configurations of every training row, each moving
   joint scaled to ``[-1, 1]`` over its training range, grouped by k-means into ``K``
   regions (k-means++ start drawn from ``seed``, Lloyd iterations to a fixed point);
   fold ``k`` holds out region ``k`` of every file.  A file whose rows all fall in one
   region stays in training;
4. **random** folds of rows (:func:`~kincal.identify.validation.fold_units`) only when
   none of these can hold anything out, and the split says so.

With more groups than ``folds`` the groups are dealt to ``folds`` folds in a permutation
drawn from ``seed``; with fewer, there is one fold per group.  The result is the ``parts``
structure of :func:`~kincal.identify.validation.fold_units` (per block, per fold, the units
held out) plus one line saying which split was used.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.identify.validation import _units, fold_units

Array = NDArray[np.float64]

__all__ = ["SplitPlan", "group_folds", "workspace_regions", "SPLITS"]

#: The ``split`` choices of :func:`group_folds`: ``auto`` (files, placements, regions,
#: then random) or ``random`` (random folds of rows / placements, the older default).
SPLITS = ("auto", "random")


@dataclass(frozen=True)
class SplitPlan:
    """How the training data are split into folds.

    Attributes:
        parts: per block, its units in ``folds`` lists (fold ``k`` holds out
            ``parts[b][k]``; an empty list holds nothing of that block), or None (the
            block is always in training).
        folds: the number of folds.
        kind: ``files``, ``placements``, ``regions`` or ``random``.
        text: one line for people: what each fold holds out.
        notes: blocks always in training and why.
    """

    parts: list[list[list[Any]] | None]
    folds: int
    kind: str
    text: str
    notes: list[str] = field(default_factory=list)


def _deal(groups: int, folds: int, seed: int) -> list[int]:
    """Fold of each group: one fold per group when ``groups <= folds``, else the groups
    dealt round-robin in a permutation drawn from ``seed``."""
    if groups <= folds:
        return list(range(groups))
    order = np.random.default_rng(seed).permutation(groups)
    fold = [0] * groups
    for i, g in enumerate(order):
        fold[int(g)] = i % folds
    return fold


def workspace_regions(q: Array, k: int, seed: int = 0, iterations: int = 100
                      ) -> NDArray[np.intp]:
    """(N,) region index ``0 .. k-1`` of each configuration: k-means of ``q`` with each
    moving joint scaled to ``[-1, 1]`` over its range (joints that do not move ignored),
    k-means++ start from ``numpy.random.default_rng(seed)``, Lloyd iterations until no
    point changes region (at most ``iterations``).  Regions are numbered by their first
    row, so the numbering does not depend on the start."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    lo, hi = q.min(axis=0), q.max(axis=0)
    moving = hi - lo > 1e-9
    if not moving.any() or k < 2 or len(q) < k:
        return np.zeros(len(q), dtype=np.intp)
    x = (q[:, moving] - 0.5 * (lo + hi)[moving]) / (0.5 * (hi - lo)[moving])
    rng = np.random.default_rng(seed)
    centres = [x[rng.integers(len(x))]]
    for _ in range(1, k):                                        # k-means++
        d2 = np.min(((x[:, None, :] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
        p = d2 / d2.sum() if d2.sum() > 0 else np.full(len(x), 1.0 / len(x))
        centres.append(x[rng.choice(len(x), p=p)])
    c = np.array(centres)
    label = np.full(len(x), -1, dtype=np.intp)
    for _ in range(iterations):
        new = np.argmin(((x[:, None, :] - c[None]) ** 2).sum(-1), axis=1).astype(np.intp)
        if np.array_equal(new, label):
            break
        label = new
        for j in range(k):
            if np.any(label == j):
                c[j] = x[label == j].mean(axis=0)
    first = {int(v): i for i, v in reversed(list(enumerate(label)))}
    renumber = {old: r for r, old in enumerate(sorted(first, key=first.__getitem__))}
    return np.array([renumber[int(v)] for v in label], dtype=np.intp)


def _by_files(blocks: Sequence[Any], folds: int, seed: int) -> SplitPlan | None:
    if len(blocks) < 2:
        return None
    fold = _deal(len(blocks), folds, seed)
    K = max(fold) + 1
    parts: list[list[list[Any]] | None] = [
        [list(_units(b)[0]) if fold[i] == k else [] for k in range(K)]
        for i, b in enumerate(blocks)]
    what = "one file" if K == len(blocks) else f"about {len(blocks) / K:.2g} files"
    return SplitPlan(parts, K, "files", f"split by file: {K} folds, each holds out {what} of "
                     f"{len(blocks)} (its own frame, marker or probe registered on it)", [])


def _by_placements(blocks: Sequence[Any], folds: int, seed: int) -> SplitPlan | None:
    groups = [(i, u) for i, b in enumerate(blocks) for u in _units(b)[0]
              if _units(b)[1] == "placements" and len(_units(b)[0]) > 1]
    if len(groups) < 2:
        return None
    fold = _deal(len(groups), folds, seed)
    K = max(fold) + 1
    held: dict[int, list[list[Any]]] = {}
    for (i, u), f in zip(groups, fold, strict=True):
        held.setdefault(i, [[] for _ in range(K)])[f].append(u)
    parts: list[list[list[Any]] | None] = [held.get(i) for i in range(len(blocks))]
    what = "one placement" if K == len(groups) else f"about {len(groups) / K:.2g} placements"
    return SplitPlan(parts, K, "placements", f"split by placement: {K} folds, each holds out "
                     f"{what} of {len(groups)}", [])


def _by_regions(blocks: Sequence[Any], folds: int, seed: int) -> SplitPlan | None:
    rows = [i for i, b in enumerate(blocks) if _units(b)[1] == "rows" and _units(b)[0]]
    if not rows:
        return None
    q = np.concatenate([np.atleast_2d(blocks[i].q) for i in rows])
    if len(q) < 2 * folds:
        return None
    label = workspace_regions(q, folds, seed)
    K = int(label.max()) + 1
    if K < 2:
        return None
    parts: list[list[list[Any]] | None] = [None] * len(blocks)
    notes, start = [], 0
    for i in rows:
        n = len(blocks[i].q)
        lab = label[start:start + n]
        start += n
        if len(set(lab.tolist())) < 2:
            notes.append(f"{blocks[i].name}: all its rows lie in one workspace region: "
                         "always in training")
            continue
        parts[i] = [np.flatnonzero(lab == k).tolist() for k in range(K)]
    if all(p is None for p in parts):
        return None
    return SplitPlan(parts, K, "regions", f"split by workspace region: {K} folds, each holds "
                     "out one region of the joint space (k-means of the scaled joint "
                     f"values, seed {seed})", notes)


def group_folds(blocks: Sequence[Any], folds: int, seed: int = 0, split: str = "auto"
                ) -> SplitPlan:
    """The folds of a model selection (module docstring): by files, placements or
    workspace regions with ``split="auto"``, random folds when none applies or with
    ``split="random"``."""
    if split not in SPLITS:
        raise ValueError(f"split {split!r} is not one of {', '.join(SPLITS)}")
    if split == "auto":
        for how in (_by_files, _by_placements, _by_regions):
            plan = how(blocks, folds, seed)
            if plan is not None:
                return plan
    parts, notes = fold_units(blocks, folds, seed)
    why = "" if split == "random" else \
        " (no files sharing a name, no placements, too few rows for workspace regions)"
    held: list[list[list[Any]] | None] = [None if p is None else [list(x) for x in p]
                                          for p in parts]
    return SplitPlan(held, folds, "random", f"random {folds}-fold split of rows and "
                     f"placements, seed {seed}{why}", notes)

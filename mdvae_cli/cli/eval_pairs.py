"""Which prediction ``mdvae eval`` scores against which ground truth: two files, or two folders
matched by relative path, then by name (``walk.npz`` with ``walk_clean.npz`` or ``walk.bvh``
cleaned into ``walk.npz``) where only one file fits."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path, PurePath

from mdvae_cli.cli.batch import print_found_notes, strip_gz
from mdvae_cli.errors import InputError
from mdvae_cli.fileio import check_regular, expand_inputs
from mdvae_cli.formats.registry import READ_SUFFIXES
from mdvae_cli.run.jobs import FileJob

#: what may join a take's name and a word a cleaning step added (walk_clean, walk-v2, walk.out)
SEPARATORS = "_-. "


@dataclass
class NoPartner:
    """A ground-truth file's job ``data`` when no one prediction could be paired with it."""

    reason: str


def base_name(rel: PurePath) -> str:
    """A file's name without its folder, ``.gz`` and format suffix: ``a/walk.bvh.gz`` -> walk."""
    return strip_gz(Path(rel)).stem


def name_fits(gt: str, pred: str) -> bool:
    """Whether prediction name ``pred`` is ground-truth name ``gt``, or it with a word added
    before or after a separator (walk_clean, clean_walk for walk)."""
    if pred == gt:
        return True
    n = len(gt)
    after = pred.startswith(gt) and len(pred) > n and pred[n] in SEPARATORS
    before = pred.endswith(gt) and len(pred) > n and pred[-n - 1] in SEPARATORS
    return after or before


def pair_by_name(
    gts: list[PurePath], preds: list[PurePath]
) -> tuple[dict[PurePath, PurePath], dict[PurePath, str], list[PurePath]]:
    """Ground truths and predictions (relative paths, none paired by path) paired by name in
    the same folder: each prediction goes to the ground truth whose name it fits
    (:func:`name_fits`), the longest such name where several fit (walk_fast_clean: walk_fast,
    not walk). Returns the pairs (ground truth -> prediction); for the ground truths no one
    prediction could be paired with although some fit, why (one line); and the predictions
    that fit no ground truth."""
    claims: dict[PurePath, list[PurePath]] = {}
    contested: dict[PurePath, str] = {}
    unfit = []
    for pred in preds:
        fits = [
            g for g in gts if g.parent == pred.parent and name_fits(base_name(g), base_name(pred))
        ]
        if not fits:
            unfit.append(pred)
            continue
        longest = max(len(base_name(g)) for g in fits)
        best = [g for g in fits if len(base_name(g)) == longest]
        if len(best) == 1:
            claims.setdefault(best[0], []).append(pred)
            continue
        names = " and ".join(g.name for g in best)
        for g in best:
            contested[g] = f"{pred.name} fits {names} alike: rename it"
    pairs, clashes = {}, {}
    for g in gts:
        mine = claims.get(g, [])
        if g in contested:
            clashes[g] = contested[g]
        elif len(mine) > 1:
            clashes[g] = (
                f"{', '.join(p.name for p in mine)} fit its name alike: rename or move all but one"
            )
        elif mine:
            pairs[g] = mine[0]
    return pairs, clashes, unfit


def pair_files(gt: Path, pred: Path) -> tuple[list[FileJob], list[Path], list[str]]:
    """Match ground truth and prediction files; jobs carry the prediction path in ``data``
    (a :class:`NoPartner` where several fit).

    Two files make one pair; two folders are matched by relative path, then by name
    (:func:`pair_by_name`); a ground-truth file with no prediction becomes a job that fails.
    Returns the jobs, the prediction files that have no ground truth, and a note for each
    pair made by name.
    """
    for p in (gt, pred):
        if not p.exists():
            raise InputError(f"no such file or folder: {p}")
    if gt.is_dir() != pred.is_dir():
        raise InputError("--gt and --pred must both be files or both be folders")
    if not gt.is_dir():
        check_regular(gt)
        check_regular(pred)
        return [FileJob(Path(gt.name), gt, data=pred)], [], []
    notes: list[str] = []
    # a prediction folder kept inside the ground truth's (or the other way) is not read as it
    gt_items = expand_inputs([gt], READ_SUFFIXES, skip=(pred,), notes=notes)
    print_found_notes(f"{gt.name}/{n}" for n in notes)
    if not gt_items:
        raise InputError(f"no motion files ({', '.join(READ_SUFFIXES)}) found in {gt}")
    # a prediction made from take.npz.gz is take.npz: pair them without .gz
    notes = []
    pred_items = expand_inputs([pred], READ_SUFFIXES, skip=(gt,), notes=notes)
    print_found_notes(f"{pred.name}/{n}" for n in notes)
    pred_by_rel = {strip_gz(rel): src for src, rel in pred_items}
    gt_rels = [strip_gz(rel) for _, rel in gt_items]
    left = [r for r in gt_rels if r not in pred_by_rel]
    by_name, clashes, unfit = pair_by_name(left, sorted(set(pred_by_rel) - set(gt_rels)))
    partner = {r: pred_by_rel[r] for r in gt_rels if r in pred_by_rel}
    partner |= {g: pred_by_rel[p] for g, p in by_name.items()}
    partner |= {g: NoPartner(why) for g, why in clashes.items()}
    jobs = [FileJob(rel, src, data=partner.get(r, pred / r))
            for (src, rel), r in zip(gt_items, gt_rels, strict=True)]  # fmt: skip
    said = [f"{g.as_posix()}: paired with {p.as_posix()} by name" for g, p in by_name.items()]
    return jobs, [pred_by_rel[rel] for rel in unfit], said

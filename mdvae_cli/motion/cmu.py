"""The CMU Graphics Lab mocap corpus as stored in ``../shared/data/cmu``: what is special about it.

* Layout: ``asfamc/<SS>/<SS>.asf`` + ``<SS>_<TT>.amc.gz``, ``bvh/<SS>_<TT>.bvh.gz`` (cmuconvert
  release), ``bvh_daz/<SS>_<TT>.bvh.gz`` (the "daz-friendly" BVH conversion: another skeleton
  of the same data) and ``asfamc_noasf/<SS>/<SS>_<TT>.amc.gz`` (no skeleton of their own:
  imported on the :data:`DONOR_SUBJECT`'s skeleton, marked as such, and kept out of every
  held-out split).
* Frame rates: the files say 120 fps, but :data:`SIXTY_HZ_SUBJECTS` were captured at 60 fps.
* Duplicates: byte-identical motions (91_xx = 105_xx) are imported once (first by subject number).
* Splits are by subject (``weights_recipe/cmu_split.json``; ``motion.corpus_plan``); only
  subjects with their own skeleton may be held out. A trial stored in two formats is imported
  once (AMC, then cmuconvert BVH, then daz BVH).

Acknowledgement required by the data's terms: "The data used in this project was obtained from
mocap.cs.cmu.edu. The database was created with funding from NSF EIA-0196217."
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

from mdvae_cli.errors import InputError
from mdvae_cli.motion.corpus_plan import CorpusItem, SplitSpec, content_hash

#: CMU subjects captured at 60 fps whose files say 120 (they play twice too fast as written)
SIXTY_HZ_SUBJECTS = frozenset(
    {"33", "34", "42", "60", "61", "62", "74", "75", "77", "79", "80", "87", "88", "89", "136"}
)
#: the frame rate CMU files declare
CMU_FPS = 120.0
#: subject whose skeleton carries the motions that lack their own (median height of the 19)
DONOR_SUBJECT = "118"
#: held-out subjects of the common kinds of motion; must equal weights_recipe/cmu_split.json
#: (a test checks)
VAL_SUBJECTS = ("06", "35")
TEST_SUBJECTS = ("02", "07", "09")
#: the folders of a CMU corpus, in the order a trial stored twice is taken from, and their kinds
FOLDERS = (("asfamc", "amc"), ("bvh", "bvh"), ("bvh_daz", "bvh_daz"), ("asfamc_noasf", "amc_donor"))

#: plain walks the manifest has no description for: CMU's index lists subject 35's first trials
#: as "walk" (they move at 1.2-1.3 m/s; 35_17-35_23 are runs)
UNDESCRIBED_WALKS = frozenset(f"35_{i:02d}" for i in range(1, 14))

_TRIAL = re.compile(r"^(\d+)_(\d+)$")
_WALK = re.compile(r"^(slow |brisk )?walk$")


def trial_of(path: Path | str) -> tuple[str, str] | None:
    """``.../07_01.amc.gz`` -> ("07", "01"); None when the name is not CMU-style."""
    name = Path(path).name
    stem = name.split(".")[0]
    m = _TRIAL.match(stem)
    return (m.group(1), m.group(2)) if m else None


def capture_fps(subject: str) -> float:
    """The rate a CMU subject was really captured at."""
    return 60.0 if subject.lstrip("0") in {s.lstrip("0") for s in SIXTY_HZ_SUBJECTS} else CMU_FPS


def is_walking(trial: str, description: str) -> bool:
    """Plain walking trials ("walk", "slow walk", "brisk walk"), for the sanity checks.
    trial: e.g. "07_01"."""
    return trial in UNDESCRIBED_WALKS or bool(_WALK.match(description.strip().lower()))


def read_manifest(root: Path) -> dict[str, str]:
    """trial id ("07_01") -> CMU description, from ``manifest.csv`` when there is one."""
    path = root / "manifest.csv"
    if not path.is_file():
        return {}
    with open(path, newline="") as fh:
        return {row["trial"]: row.get("description") or "" for row in csv.DictReader(fh)}


def default_split() -> SplitSpec:
    """The held-out subjects when no split file is given."""
    return SplitSpec(val=VAL_SUBJECTS, test=TEST_SUBJECTS)


def is_cmu_corpus(root: Path) -> bool:
    """Whether ``root`` has the layout of a CMU corpus folder."""
    return any((Path(root) / d).is_dir() for d, _ in FOLDERS)


def plan_corpus(root: Path | str, spec: SplitSpec) -> list[CorpusItem]:
    """Every trial under a CMU corpus folder, with its skeleton, true fps and split.

    Raises InputError when the folder does not have the expected layout, the donor skeleton is
    missing, or a held-out CMU subject has no skeleton of its own.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"no such folder: {root}")
    if not is_cmu_corpus(root):
        names = ", ".join(f"{d}/" for d, _ in FOLDERS)
        raise InputError(f"{root}: not a CMU corpus folder (none of {names})")
    notes = read_manifest(root)
    items: list[CorpusItem] = []
    own_skeleton: set[str] = set()

    def motions(folder: Path, suffix: str) -> list[Path]:
        if not folder.is_dir():
            return []
        return sorted(p for p in folder.rglob("*") if p.is_file() and not p.name.startswith(".")
                      and p.name.removesuffix(".gz").endswith(suffix))  # fmt: skip

    def add(path: Path, kind: str, skeleton: Path | None) -> None:
        ids = trial_of(path)
        if ids is None:
            raise InputError(f"{path}: not a CMU trial name (<subject>_<trial>)")
        subject, trial = ids
        note = notes.get(f"{subject}_{trial}", "")
        items.append(CorpusItem(path, path.relative_to(root), kind, subject, trial, skeleton,
                                capture_fps(subject), None, note))  # fmt: skip
        if kind != "amc_donor":
            own_skeleton.add(subject)

    for path in motions(root / "asfamc", ".amc"):
        subject = trial_of(path)[0] if trial_of(path) else ""
        asf = path.parent / f"{subject}.asf"
        if not asf.is_file():
            raise InputError(f"{path}: its skeleton {asf.name} is missing")
        add(path, "amc", asf)
    for folder, kind in (("bvh", "bvh"), ("bvh_daz", "bvh_daz")):
        for path in motions(root / folder, ".bvh"):
            add(path, kind, None)
    noasf = motions(root / "asfamc_noasf", ".amc")
    if noasf:
        donor = root / "asfamc" / DONOR_SUBJECT / f"{DONOR_SUBJECT}.asf"
        if not donor.is_file():
            raise InputError(f"donor skeleton {donor} is missing")
        for path in noasf:
            add(path, "amc_donor", donor)

    for subject in spec.held_out():
        if subject.isdigit() and subject not in own_skeleton:
            raise InputError(f"held-out subject {subject} has no motions with its own skeleton")
    rank = {kind: i for i, (_, kind) in enumerate(FOLDERS)}
    seen: dict[str, Path] = {}
    trials: dict[tuple[str, str], Path] = {}
    for item in sorted(items, key=lambda i: (int(i.subject), int(i.trial), rank[i.kind])):
        key = (str(int(item.subject)), str(int(item.trial)))
        if key in trials:
            taken = trials[key].as_posix()
            item.skip = f"trial {item.subject}_{item.trial} already taken from {taken}"
            continue
        digest = content_hash(item.path)
        if digest in seen:
            item.skip = f"duplicate of {seen[digest].as_posix()}"
            continue
        seen[digest] = item.relpath
        trials[key] = item.relpath
        split = spec.split_of(item.subject)
        if item.donor and split != "train":
            item.skip = f"donor-skeleton motion of held-out subject {item.subject}"
            continue
        item.split = split
    return items


# --- summaries ---------------------------------------------------------------------------------

ACKNOWLEDGEMENT = (
    "The data used in this project was obtained from mocap.cs.cmu.edu. "
    "The database was created with funding from NSF EIA-0196217."
)


def walking_summary(rows: list[dict]) -> dict:
    """The walking-trial checks of an imported CMU corpus: mean lowest-sole height and speed
    of the plain walks (``rows`` as the importer returns them, with subject, trial and
    description)."""
    walks = [r for r in rows if r.get("trial") and r["subject"].isdigit()
             and is_walking(f"{r['subject']}_{r['trial']}", r["description"])]  # fmt: skip
    walking = {"files": len(walks), "sole_height_mean_cm": None, "speed_mps": None, "trials": {}}
    if walks:
        checks = ("sole_height_mean_cm", "speed_mps")
        speeds = [r["speed_mps"] for r in walks]
        walking.update(
            sole_height_mean_cm=round(sum(r["sole_height_mean_cm"] for r in walks) / len(walks), 2),
            speed_mps={"min": min(speeds), "mean": round(sum(speeds) / len(speeds), 3),
                       "max": max(speeds)},
            trials={f"{r['subject']}_{r['trial']}": {k: r[k] for k in checks} for r in walks},
        )  # fmt: skip
    return walking

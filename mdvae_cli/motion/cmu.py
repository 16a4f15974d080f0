"""The CMU Graphics Lab mocap corpus as stored in ``../shared/data/cmu``: what is special about it.

* Layout: ``asfamc/<SS>/<SS>.asf`` + ``<SS>_<TT>.amc.gz``, ``bvh/<SS>_<TT>.bvh.gz`` (cmuconvert
  release) and ``asfamc_noasf/<SS>/<SS>_<TT>.amc.gz`` (no skeleton of their own: imported on
  the :data:`DONOR_SUBJECT`'s skeleton, marked as such, and kept out of validation and test).
* Frame rates: the files say 120 fps, but :data:`SIXTY_HZ_SUBJECTS` were captured at 60 fps.
* Duplicates: byte-identical motions (91_xx = 105_xx) are imported once (first by subject number).
* Splits are by subject (``weights_recipe/cmu_split.json``, mirrored by :data:`VAL_SUBJECTS` and
  :data:`TEST_SUBJECTS`); only subjects with their own skeleton may be held out.

Acknowledgement required by the data's terms: "The data used in this project was obtained from
mocap.cs.cmu.edu. The database was created with funding from NSF EIA-0196217."
"""

from __future__ import annotations

import csv
import gzip
import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path

from mdvae_cli.errors import InputError

#: CMU subjects captured at 60 fps whose files say 120 (they play twice too fast as written)
SIXTY_HZ_SUBJECTS = frozenset(
    {"33", "34", "42", "60", "61", "62", "74", "75", "77", "79", "80", "87", "88", "89", "136"}
)
#: the frame rate CMU files declare
CMU_FPS = 120.0
#: subject whose skeleton carries the motions that lack their own (median height of the 19)
DONOR_SUBJECT = "118"
#: held-out subjects; must equal weights_recipe/cmu_split.json (a test checks)
VAL_SUBJECTS = ("06", "35")
TEST_SUBJECTS = ("02", "07", "09")

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


@dataclass
class SplitSpec:
    """Held-out subjects (CMU numbers as in file names, e.g. "07")."""

    val: tuple[str, ...] = VAL_SUBJECTS
    test: tuple[str, ...] = TEST_SUBJECTS

    def split_of(self, subject: str) -> str:
        if subject in self.test:
            return "test"
        if subject in self.val:
            return "val"
        return "train"


def load_split_spec(path: Path | str | None) -> SplitSpec:
    """Read a split file ``{"val_subjects": [...], "test_subjects": [...]}``; None -> defaults."""
    if path is None:
        return SplitSpec()
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        val, test = data["val_subjects"], data["test_subjects"]
    except FileNotFoundError:
        raise InputError(f"no such split file: {path}") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a split file with val_subjects and test_subjects "
                         f"({type(exc).__name__}: {exc})") from None  # fmt: skip
    if not all(isinstance(s, str) for s in [*val, *test]):
        raise InputError(f'{path}: subjects must be strings such as "07"')
    if set(val) & set(test):
        raise InputError(f"{path}: a subject is in both val and test")
    return SplitSpec(tuple(val), tuple(test))


@dataclass
class CorpusItem:
    """One CMU trial to import.

    path: input file; relpath: path below the corpus root; kind: "amc", "bvh" or "amc_donor";
    skeleton: the .asf to use (AMC only); fps: the true capture rate; split: train/val/test, or
    None when the file is skipped, with ``skip`` saying why.
    """

    path: Path
    relpath: Path
    kind: str
    subject: str
    trial: str
    skeleton: Path | None
    fps: float
    split: str | None
    description: str = ""
    skip: str | None = None

    @property
    def donor(self) -> bool:
        return self.kind == "amc_donor"


def read_manifest(root: Path) -> dict[str, str]:
    """trial id ("07_01") -> CMU description, from ``manifest.csv`` when there is one."""
    path = root / "manifest.csv"
    if not path.is_file():
        return {}
    with open(path, newline="") as fh:
        return {row["trial"]: row.get("description") or "" for row in csv.DictReader(fh)}


def _content_hash(path: Path) -> str:
    opener = gzip.open if path.suffix == ".gz" else open
    digest = hashlib.sha256()
    with opener(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def plan_corpus(root: Path | str, spec: SplitSpec | None = None) -> list[CorpusItem]:
    """Every trial under a CMU corpus folder, with its skeleton, true fps and split.

    Raises InputError when the folder does not have the expected layout, the donor skeleton is
    missing, or a held-out subject has no skeleton of its own.
    """
    root = Path(root)
    spec = spec or SplitSpec()
    if not root.is_dir():
        raise InputError(f"no such folder: {root}")
    found = [root / d for d in ("asfamc", "bvh", "asfamc_noasf") if (root / d).is_dir()]
    if not found:
        raise InputError(f"{root}: not a CMU corpus folder (no asfamc/, bvh/ or asfamc_noasf/)")
    notes = read_manifest(root)
    items: list[CorpusItem] = []
    own_skeleton: set[str] = set()

    def motions(folder: Path, suffix: str) -> list[Path]:
        return sorted(p for p in folder.rglob("*") if p.is_file() and not p.name.startswith(".")
                      and p.name.removesuffix(".gz").endswith(suffix))  # fmt: skip

    def add(path: Path, kind: str, skeleton: Path | None) -> None:
        ids = trial_of(path)
        if ids is None:
            raise InputError(f"{path}: not a CMU trial name (<subject>_<trial>)")
        subject, trial = ids
        items.append(
            CorpusItem(
                path,
                path.relative_to(root),
                kind,
                subject,
                trial,
                skeleton,
                capture_fps(subject),
                None,
                notes.get(f"{subject}_{trial}", ""),
            )
        )

    for path in motions(root / "asfamc", ".amc") if (root / "asfamc").is_dir() else []:
        subject = trial_of(path)[0] if trial_of(path) else ""
        asf = path.parent / f"{subject}.asf"
        if not asf.is_file():
            raise InputError(f"{path}: its skeleton {asf.name} is missing")
        own_skeleton.add(subject)
        add(path, "amc", asf)
    for path in motions(root / "bvh", ".bvh") if (root / "bvh").is_dir() else []:
        add(path, "bvh", None)
        own_skeleton.add(items[-1].subject)
    noasf = motions(root / "asfamc_noasf", ".amc") if (root / "asfamc_noasf").is_dir() else []
    if noasf:
        donor = root / "asfamc" / DONOR_SUBJECT / f"{DONOR_SUBJECT}.asf"
        if not donor.is_file():
            raise InputError(f"donor skeleton {donor} is missing")
        for path in noasf:
            add(path, "amc_donor", donor)

    for subject in (*spec.val, *spec.test):
        if subject not in own_skeleton:
            raise InputError(f"held-out subject {subject} has no motions with its own skeleton")
    seen: dict[str, Path] = {}
    for item in sorted(items, key=lambda i: (int(i.subject), int(i.trial), i.kind)):
        digest = _content_hash(item.path)
        if digest in seen:
            item.skip = f"duplicate of {seen[digest].as_posix()}"
            continue
        seen[digest] = item.relpath
        split = spec.split_of(item.subject)
        if item.donor and split != "train":
            item.skip = f"donor-skeleton motion of held-out subject {item.subject}"
            continue
        item.split = split
    return items


# --- summaries ---------------------------------------------------------------------------------
# ``rows`` are per-file dicts as the importer returns them: format, frames, retarget_error_mm,
# retarget_error_direct_mm, sole_height_mean_cm, speed_mps, output, and for corpus files
# subject, trial, split, description, donor_skeleton.

ACKNOWLEDGEMENT = (
    "The data used in this project was obtained from mocap.cs.cmu.edu. "
    "The database was created with funding from NSF EIA-0196217."
)


def frame_weighted(rows: list[dict], key: str) -> float | None:
    """Mean of ``key`` over rows weighted by their frames (None for no frames)."""
    frames = sum(r["frames"] for r in rows)
    if not frames:
        return None
    return round(sum(r[key] * r["frames"] for r in rows) / frames, 2)


def error_summary(rows: list[dict]) -> dict:
    """Frames and mean joint error overall and per format."""
    by_format = {}
    for fmt in sorted({r["format"] for r in rows}):
        sub = [r for r in rows if r["format"] == fmt]
        by_format[fmt] = {
            "files": len(sub),
            "frames": sum(r["frames"] for r in sub),
            "retarget_error_mm": frame_weighted(sub, "retarget_error_mm"),
        }
    return {
        "frames": sum(r["frames"] for r in rows),
        "retarget_error_mm": frame_weighted(rows, "retarget_error_mm"),
        "retarget_error_direct_mm": frame_weighted(rows, "retarget_error_direct_mm"),
        "by_format": by_format,
    }


def corpus_summary(rows: list[dict]) -> dict:
    """Per-split counts and the walking-trial checks (sole height, speed)."""
    splits = {}
    for name in ("train", "val", "test"):
        sub = [r for r in rows if r["split"] == name]
        splits[name] = {"files": len(sub), "frames": sum(r["frames"] for r in sub),
                        "subjects": sorted({r["subject"] for r in sub}, key=int)}  # fmt: skip
    walks = [r for r in rows if is_walking(f"{r['subject']}_{r['trial']}", r["description"])]
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
    return {"splits": splits, "walking": walking, "acknowledgement": ACKNOWLEDGEMENT}


def split_document(rows: list[dict], spec: SplitSpec, fps: float | None) -> dict:
    """The ``split.json`` written next to a converted corpus.

    ``splits``: {"train"|"val"|"test": [output paths relative to the split file's folder]};
    ``donor_skeleton``: outputs imported on the donor skeleton (all in train).
    """

    def outputs(pred) -> list[str]:
        return sorted(r["output"] for r in rows if pred(r))

    return {
        "format": "mdvae-cmu-split/1",
        "fps": fps,
        "val_subjects": list(spec.val),
        "test_subjects": list(spec.test),
        "splits": {
            name: outputs(lambda r, n=name: r["split"] == n) for name in ("train", "val", "test")
        },  # fmt: skip
        "subjects": {
            name: sorted({r["subject"] for r in rows if r["split"] == name}, key=int)
            for name in ("train", "val", "test")
        },  # fmt: skip
        "donor_skeleton": outputs(lambda r: r["donor_skeleton"]),
    }

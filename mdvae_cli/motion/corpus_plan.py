"""Mocap corpus folders planned for import (``mdvae import --corpus``): one item per motion file
with its skeleton, true frame rate and split; the split file that assigns whole subjects to
splits; and the ``split.json`` / summary written next to a converted corpus.

Splits are by subject (a person), never by window or trial:

* ``train`` — everything not held out (the shipped weights train on it);
* ``val`` and ``test`` — held-out CMU subjects doing the corpus's common motion (walks, runs);
* ``unseen_val`` and ``unseen_test`` — held-out subjects doing *kinds* of motion that training
  does not have (another lab's actors, dance, martial arts, acrobatics, sports): ``unseen_val``
  may guide choices (augmentation, settings), ``unseen_test`` is only ever measured.

A subject is a CMU number as in file names ("07") or ``<corpus>:<actor>`` for other corpora
("hdm05:bd"). Corpora that may not train shipped weights (HDM05, CC BY-SA) put every actor that
no split names out of the corpus, with the reason.
"""

from __future__ import annotations

import gzip
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from mdvae_cli.errors import InputError

#: every split a corpus can have, in the order split files and summaries list them
SPLITS = ("train", "val", "test", "unseen_val", "unseen_test")
#: held-out splits and the split-file key naming their subjects
HELD_OUT_KEYS = {
    "val": "val_subjects",
    "test": "test_subjects",
    "unseen_val": "unseen_val_subjects",
    "unseen_test": "unseen_test_subjects",
}
#: the split-file keys that must be present (the unseen ones are optional)
REQUIRED_KEYS = ("val_subjects", "test_subjects")


@dataclass
class SplitSpec:
    """Held-out subjects per split (strings such as "07" or "hdm05:bd"); the rest is train."""

    val: tuple[str, ...] = ()
    test: tuple[str, ...] = ()
    unseen_val: tuple[str, ...] = ()
    unseen_test: tuple[str, ...] = ()

    def split_of(self, subject: str) -> str:
        for name in ("test", "unseen_test", "val", "unseen_val"):
            if subject in getattr(self, name):
                return name
        return "train"

    def held_out(self) -> tuple[str, ...]:
        return (*self.val, *self.test, *self.unseen_val, *self.unseen_test)

    def to_dict(self) -> dict[str, list[str]]:
        return {key: list(getattr(self, name)) for name, key in HELD_OUT_KEYS.items()}


def load_split_spec(path: Path | str | None, default: SplitSpec | None = None) -> SplitSpec:
    """Read a split file ``{"val_subjects": [...], "test_subjects": [...],
    "unseen_val_subjects": [...], "unseen_test_subjects": [...]}`` (the unseen ones optional);
    None -> ``default`` (or no held-out subjects). Other keys (e.g. "about") are ignored."""
    if path is None:
        return default or SplitSpec()
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        lists = {
            name: data[key] if key in REQUIRED_KEYS else data.get(key, [])
            for name, key in HELD_OUT_KEYS.items()
        }
    except FileNotFoundError:
        raise InputError(f"no such split file: {path}") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a split file with val_subjects and test_subjects "
                         f"({type(exc).__name__}: {exc})") from None  # fmt: skip
    for key, subjects in zip(HELD_OUT_KEYS.values(), lists.values(), strict=True):
        if not isinstance(subjects, list) or not all(isinstance(s, str) for s in subjects):
            raise InputError(f'{path}: {key} must be a list of strings such as "07"')
    seen: dict[str, str] = {}
    for name, subjects in lists.items():
        for s in subjects:
            if s in seen:
                raise InputError(f"{path}: subject {s} is in both {seen[s]} and {name}")
            seen[s] = name
    return SplitSpec(**{name: tuple(v) for name, v in lists.items()})


@dataclass
class CorpusItem:
    """One motion file to import.

    path: input file; relpath: path below the output root; kind: "amc", "bvh", "bvh_daz" or
    "amc_donor" (an AMC on a donor skeleton); subject, trial: who and which take; skeleton: the
    .asf to use (AMC only); fps: the true capture rate; split: one of :data:`SPLITS`, or None
    when the file is skipped, with ``skip`` saying why.
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


def content_hash(path: Path) -> str:
    """SHA-256 of a file's (uncompressed, for .gz) content."""
    opener = gzip.open if path.suffix == ".gz" else open
    digest = hashlib.sha256()
    with opener(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def subject_order(subject: str) -> tuple:
    """Sort key: CMU numbers numerically, then other corpora's actors by name."""
    return (0, int(subject), "") if subject.isdigit() else (1, 0, subject)


# --- summaries ---------------------------------------------------------------------------------
# ``rows`` are per-file dicts as the importer returns them: format, frames, retarget_error_mm,
# retarget_error_direct_mm, sole_height_mean_cm, speed_mps, output, and for corpus files
# subject, trial, split, description, donor_skeleton.


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


def split_summary(rows: list[dict], fps: float | None) -> dict:
    """Per split: files, frames, minutes (at ``fps``, the output rate; None when the sources'
    rates were kept) and subjects."""
    splits = {}
    for name in SPLITS:
        sub = [r for r in rows if r["split"] == name]
        frames = sum(r["frames"] for r in sub)
        seconds = sum(r["frames"] / r["fps"] for r in sub)
        subjects = sorted({r["subject"] for r in sub}, key=subject_order)
        minutes = round(seconds / 60, 2)
        splits[name] = {"files": len(sub), "frames": frames, "minutes": minutes,
                        "subjects": subjects}  # fmt: skip
    return splits


def split_document(rows: list[dict], spec: SplitSpec, fps: float | None) -> dict:
    """The ``split.json`` written next to a converted corpus.

    ``splits``: {split: [output paths relative to the split file's folder]} for every split of
    :data:`SPLITS`; ``subjects``: who is in each; ``donor_skeleton``: outputs imported on a
    donor skeleton (all in train).
    """

    def outputs(pred) -> list[str]:
        return sorted(r["output"] for r in rows if pred(r))

    return {
        "format": "mdvae-corpus-split/2",
        "fps": fps,
        **spec.to_dict(),
        "splits": {name: outputs(lambda r, n=name: r["split"] == n) for name in SPLITS},
        "subjects": {
            name: sorted({r["subject"] for r in rows if r["split"] == name}, key=subject_order)
            for name in SPLITS
        },  # fmt: skip
        "donor_skeleton": outputs(lambda r: r["donor_skeleton"]),
    }

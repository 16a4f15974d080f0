"""The HDM05 mocap database (Max-Planck-Institut für Informatik / Universität Bonn) as stored in
``../shared/data/hdm05``: ``<actor>/<actor>.asf`` + ``HDM_<actor>_<action>_<NNN>_120.amc.gz``,
Acclaim ASF/AMC at 120 fps, four actors (bd, bk, dg, mm) of another lab than CMU.

Its licence (CC BY-SA 3.0) leaves open whether weights trained on it must be shared alike, so
it never trains the shipped weights: every actor is held out, in a split the split file names
(``"hdm05:bd"`` in ``unseen_val_subjects`` or ``unseen_test_subjects``); an actor no split
names is left out with that reason.

Cite: Müller, Röder, Clausen, Eberhardt, Krüger, Weber, "Documentation Mocap Database HDM05",
Universität Bonn, Tech. Rep. CG-2007-2, 2007.
"""

from __future__ import annotations

import re
from pathlib import Path

from mdvae_cli.errors import InputError
from mdvae_cli.motion.corpus_plan import CorpusItem, SplitSpec

#: the frame rate of every HDM05 clip (the ``_120`` in its name)
HDM05_FPS = 120.0
#: how split files name an HDM05 actor: "hdm05:<actor>"
PREFIX = "hdm05:"

_CLIP = re.compile(r"^HDM_([a-z]+)_(.+)_120$")


def is_hdm05_corpus(root: Path) -> bool:
    """Whether ``root`` holds actor folders with HDM05 clips."""
    root = Path(root)
    return root.is_dir() and any(
        p.is_dir() and any(c.name.startswith(f"HDM_{p.name}_") for c in p.iterdir())
        for p in root.iterdir()
        if not p.name.startswith(".")
    )


def plan_hdm05(root: Path | str, spec: SplitSpec) -> list[CorpusItem]:
    """Every clip under an HDM05 folder with its actor's skeleton and split (held-out only).

    InputError when an actor's skeleton is missing or a clip is misnamed."""
    root = Path(root)
    items: list[CorpusItem] = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        actor = folder.name
        asf = folder / f"{actor}.asf"
        clips = sorted(p for p in folder.iterdir()
                       if p.is_file() and p.name.removesuffix(".gz").endswith(".amc"))  # fmt: skip
        if not clips:
            continue
        if not asf.is_file():
            raise InputError(f"{folder}: its skeleton {asf.name} is missing")
        subject = PREFIX + actor
        split = spec.split_of(subject)
        for path in clips:
            m = _CLIP.match(path.name.removesuffix(".gz").removesuffix(".amc"))
            if m is None or m.group(1) != actor:
                raise InputError(f"{path}: not an HDM05 clip name (HDM_{actor}_<action>_120.amc)")
            item = CorpusItem(path, path.relative_to(root), "amc", subject, m.group(2), asf,
                              HDM05_FPS, None, m.group(2))  # fmt: skip
            if split == "train":
                item.skip = f"HDM05 ({subject}) is test data only (CC BY-SA); no split names it"
            else:
                item.split = split
            items.append(item)
    return items

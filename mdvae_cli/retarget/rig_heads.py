"""The head of a rig that names none (``retarget.joint_map`` finds the others by name): a
3ds Max CAT rig's numbered hubs, or a neck whose only child is an End Site (Poser and DAZ
figures: ``hip, abdomen, chest, neck`` and no head joint)."""

from __future__ import annotations

import re

import numpy as np

from mdvae_cli.formats.source import SourceMotion

#: names of a neck (normalised, ``joint_map.normalise_name``) whose End Site may be the head
NECKS = ("neck", "neck2", "neckupper", "upperneck")


def cat_head(src: SourceMotion, norm: dict[str, int], anchor: dict[str, int]) -> int | None:
    """The head of a 3ds Max CAT rig built from scratch, whose hubs are numbered as made
    (``Hub001`` the pelvis, ``Hub002`` the ribcage, ``Hub003`` the head): of its hubs that
    carry no arm (no shoulder below them), the deepest; None without hubs or shoulders."""
    shoulders = [anchor[k] for k in ("left_shoulder", "right_shoulder") if k in anchor]
    hubs = [j for name, j in norm.items() if re.fullmatch(r"hub\d+", name)]
    if not shoulders or not hubs:
        return None

    def above(j: int) -> list[int]:
        out = []
        while j >= 0:
            out.append(j)
            j = int(src.parents[j])
        return out

    armless = [h for h in hubs if not any(h in above(s) for s in shoulders)]
    return max(armless, key=lambda h: len(above(h)), default=None)


def neck_end(src: SourceMotion, norm: dict[str, int]) -> int | None:
    """The End Site of a rig's neck, taken as the head: a neck (:data:`NECKS`) whose only
    child is an End Site, the rig's top (a note says so); None elsewhere."""
    for name in NECKS:
        if name in norm:
            kids = np.flatnonzero(src.parents == norm[name])
            if len(kids) == 1 and src.end_site[kids[0]]:
                note = f"no head joint: the head is at the end of {src.names[norm[name]]}"
                if note not in src.notes:
                    src.notes.append(note)
                return int(kids[0])
    return None

"""The CJK fonts a Chinese certificate, report figure and loop figure are set in: found on disk by file name (the
fonts of Debian's fonts-noto-cjk, or WenQuanYi), so a font installed after matplotlib built its font cache is
found too, and registered with matplotlib when a figure needs one."""

from __future__ import annotations

import functools
from pathlib import Path

FONT_DIRS = (Path("/usr/share/fonts"), Path("/usr/local/share/fonts"), Path.home() / ".local/share/fonts",
             Path.home() / ".fonts")
#: (file name, family for the certificate's serif text, family for figures' sans text), preferred first
CJK_FILES = (("NotoSerifCJK-Regular.ttc", "Noto Serif CJK SC"), ("NotoSansCJK-Regular.ttc", "Noto Sans CJK SC"),
             ("wqy-microhei.ttc", "WenQuanYi Micro Hei"))


@functools.cache
def cjk_fonts() -> tuple[tuple[str, Path], ...]:
    """(family, file) of each installed CJK font of :data:`CJK_FILES`, in its order."""
    found = []
    for name, family in CJK_FILES:
        for base in FONT_DIRS:
            hits = sorted(base.rglob(name)) if base.is_dir() else []
            if hits:
                found.append((family, hits[0]))
                break
    return tuple(found)


def figure_families() -> list[str]:
    """matplotlib's ``font.family`` for figures with CJK words: DejaVu Sans, then an installed CJK sans (registered
    with matplotlib here), glyph by glyph."""
    from matplotlib import font_manager

    families = ["DejaVu Sans"]
    for family, path in cjk_fonts():
        if "Serif" in family:
            continue
        known = {entry.name for entry in font_manager.fontManager.ttflist}
        if family not in known:
            font_manager.fontManager.addfont(str(path))
        families.append(family)
        break
    return families

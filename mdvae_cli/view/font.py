"""A tiny bitmap font for figures written without a plotting library: 5 x 7 pixel glyphs for
printable ASCII (and the degree sign), drawn here. Each glyph is seven rows, top first, as two
hex digits each; bit 4 is the leftmost of the five columns.
"""

from __future__ import annotations

import numpy as np

GLYPH_WIDTH, GLYPH_HEIGHT = 5, 7
#: pixels from one character to the next, and from one line to the next, at scale 1
ADVANCE, LINE_HEIGHT = 6, 9

# fmt: off
GLYPHS = {
    ' ': "00000000000000", '!': "04040404040004", '"': "0A0A0A00000000", '#': "0A0A1F0A1F0A0A",
    '$': "040F140E051E04", '%': "18190204081303", '&': "0C12140815120D", "'": "04040800000000",
    '(': "02040808080402", ')': "08040202020408", '*': "0004150E150400", '+': "0004041F040400",
    ',': "000000000C0408", '-': "0000001F000000", '.': "00000000000C0C", '/': "00010204081000",
    '0': "0E11131519110E", '1': "040C040404040E", '2': "0E11010204081F", '3': "1F02040201110E",
    '4': "02060A121F0202", '5': "1F101E0101110E", '6': "0608101E11110E", '7': "1F010204080808",
    '8': "0E11110E11110E", '9': "0E11110F01020C", ':': "000C0C000C0C00", ';': "000C0C000C0408",
    '<': "02040810080402", '=': "00001F001F0000", '>': "08040201020408", '?': "0E110102040004",
    '@': "0E11010D15150E", 'A': "0E11111F111111", 'B': "1E11111E11111E", 'C': "0E11101010110E",
    'D': "1C12111111121C", 'E': "1F10101E10101F", 'F': "1F10101E101010", 'G': "0E11101711110F",
    'H': "1111111F111111", 'I': "0E04040404040E", 'J': "0702020202120C", 'K': "11121418141211",
    'L': "1010101010101F", 'M': "111B1515111111", 'N': "11111915131111", 'O': "0E11111111110E",
    'P': "1E11111E101010", 'Q': "0E11111115120D", 'R': "1E11111E141211", 'S': "0F10100E01011E",
    'T': "1F040404040404", 'U': "1111111111110E", 'V': "11111111110A04", 'W': "1111111515150A",
    'X': "11110A040A1111", 'Y': "1111110A040404", 'Z': "1F01020408101F", '[': "0E08080808080E",
    '\\': "00100804020100", ']': "0E02020202020E", '^': "040A1100000000", '_': "0000000000001F",
    '`': "08040200000000", 'a': "00000E010F110F", 'b': "1010161911111E", 'c': "00000E1010110E",
    'd': "01010D1311110F", 'e': "00000E111F100E", 'f': "0609081C080808", 'g': "000F11110F010E",
    'h': "10101619111111", 'i': "04000C0404040E", 'j': "0200060202120C", 'k': "10101214181412",
    'l': "0C04040404040E", 'm': "00001A15151111", 'n': "00001619111111", 'o': "00000E1111110E",
    'p': "00001E111E1010", 'q': "00000D130F0101", 'r': "00001619101010", 's': "00000E100E011E",
    't': "08081C08080906", 'u': "0000111111130D", 'v': "00001111110A04", 'w': "0000111115150A",
    'x': "0000110A040A11", 'y': "000011110F010E", 'z': "00001F0204081F", '{': "03040408040403",
    '|': "04040404040404", '}': "18040402040418", '~': "00000815020000", '°': "0C12120C000000",
    '·': "0000000C0C0000",
}
# fmt: on


def glyph(char: str) -> np.ndarray:
    """(7, 5) bool bitmap of one character; an unknown one is drawn as a box."""
    code = GLYPHS.get(char)
    if code is None:
        box = np.ones((GLYPH_HEIGHT, GLYPH_WIDTH), dtype=bool)
        box[1:-1, 1:-1] = False
        return box
    rows = [int(code[i : i + 2], 16) for i in range(0, 2 * GLYPH_HEIGHT, 2)]
    return np.array([[(r >> (4 - c)) & 1 for c in range(GLYPH_WIDTH)] for r in rows], dtype=bool)


def text_size(text: str, scale: int = 1) -> tuple[int, int]:
    """(width, height) in pixels of one line of ``text`` at integer ``scale``."""
    if not text:
        return 0, GLYPH_HEIGHT * scale
    return (ADVANCE * len(text) - 1) * scale, GLYPH_HEIGHT * scale


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """The pixels of one line of ``text``.  -> (7 * scale, width) bool"""
    width, height = text_size(text, scale)
    mask = np.zeros((GLYPH_HEIGHT, max(ADVANCE * len(text) - 1, 0)), dtype=bool)
    for i, char in enumerate(text):
        mask[:, i * ADVANCE : i * ADVANCE + GLYPH_WIDTH] = glyph(char)
    if scale > 1:
        mask = np.kron(mask, np.ones((scale, scale), dtype=bool))
    return mask[:height, :width]

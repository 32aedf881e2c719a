"""Pictures of Messenger observations: a text board for the terminal, PNG frames and strips, GIFs.

Everything here reads only the observation, so a picture shows what a player (or a world model)
sees: identities and the avatar, never roles or movements, which the manual alone tells.

Symbols (`IDENTITY_LETTERS`, plus the avatar and the empty cell):

- each of the 12 identities has its own capital letter (A airplane, M mage, D dog, ...);
- '@' is the avatar without the message, '&' the avatar carrying it, '.' an empty cell;
- when the avatar shares a cell with an entity, the avatar is shown (the sprite under it is
  mentioned in the legend): that is the sprite the player steers;
- when two entities share a cell without the avatar, the cell shows '*' and the legend names
  them, since one letter cannot show both.

Inputs are single observations, either the grid form [10, 10, 4] or the compact form [4, 3]
(id, row, col per channel); sequences are [T, 10, 10, 4] or [T, 4, 3].
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..errors import ShapeError
from .constants import (
    ACTION_NAMES,
    AVATAR_NO_MESSAGE,
    AVATAR_WITH_MESSAGE,
    GRID,
    ID_TO_IDENTITY,
    IDENTITIES,
    NUM_ACTIONS,
    NUM_CHANNELS,
    WALL,
)
from .engine import compact_to_grid

IDENTITY_LETTERS: dict[str, str] = {
    "airplane": "A",
    "mage": "M",
    "dog": "D",
    "bird": "B",
    "fish": "F",
    "scientist": "S",
    "thief": "T",
    "ship": "H",
    "ball": "L",
    "robot": "R",
    "queen": "Q",
    "sword": "W",
}
"""One distinct capital letter per identity."""
AVATAR_LETTER = "@"
AVATAR_MESSAGE_LETTER = "&"
EMPTY_LETTER = "."
OVERLAP_LETTER = "*"
WALL_LETTER = "#"
UNKNOWN_LETTER = "?"

_ID_LETTERS: dict[int, str] = {IDENTITIES[name]: letter for name, letter in IDENTITY_LETTERS.items()}
_ID_LETTERS[AVATAR_NO_MESSAGE] = AVATAR_LETTER
_ID_LETTERS[AVATAR_WITH_MESSAGE] = AVATAR_MESSAGE_LETTER

# ANSI foreground colours per identity (6 normal + 6 bright), so that letters stay told apart by
# colour too; the avatar is drawn in reverse video so it stands out from every entity.
_ANSI_IDENTITY: dict[str, str] = {
    "airplane": "31",
    "mage": "32",
    "dog": "33",
    "bird": "34",
    "fish": "35",
    "scientist": "36",
    "thief": "91",
    "ship": "92",
    "ball": "93",
    "robot": "94",
    "queen": "95",
    "sword": "96",
}
_ANSI_AVATAR = "1;7"  # bold, reverse video
_ANSI_AVATAR_MESSAGE = "1;30;43"  # bold black on yellow: "carrying the message"
_ANSI_EMPTY = "2"  # dim
_ANSI_OVERLAP = "1;97;41"
_ANSI_RESET = "\x1b[0m"

# RGB cell colours of the PNG frames, per identity, for the avatar and for the background.
_RGB_IDENTITY: dict[str, tuple[int, int, int]] = {
    "airplane": (230, 25, 75),
    "mage": (60, 180, 75),
    "dog": (255, 225, 25),
    "bird": (0, 130, 200),
    "fish": (245, 130, 48),
    "scientist": (145, 30, 180),
    "thief": (70, 240, 240),
    "ship": (240, 50, 230),
    "ball": (210, 245, 60),
    "robot": (0, 128, 128),
    "queen": (220, 190, 255),
    "sword": (170, 110, 40),
}
_RGB_AVATAR = (40, 40, 40)
_RGB_AVATAR_MESSAGE = (255, 200, 0)
_RGB_OVERLAP = (128, 128, 128)
_RGB_EMPTY = (245, 245, 245)
_RGB_GRID_LINE = (190, 190, 190)
_RGB_CAPTION_BG = (255, 255, 255)
_RGB_TEXT = (0, 0, 0)


# --------------------------------------------------------------------------- observations
def _as_grid(obs: np.ndarray) -> np.ndarray:
    """One observation as a [10, 10, 4] grid; the compact form is converted."""
    arr = np.asarray(obs)
    if arr.shape == (GRID, GRID, NUM_CHANNELS):
        return arr
    if arr.shape == (NUM_CHANNELS, 3):
        return compact_to_grid(arr)
    raise ShapeError(
        f"an observation is a grid ({GRID}, {GRID}, {NUM_CHANNELS}) or compact ({NUM_CHANNELS}, 3) array, "
        f"got shape {arr.shape}"
    )


def _as_grids(observations: np.ndarray | Sequence[np.ndarray]) -> np.ndarray:
    """A sequence of observations as [T, 10, 10, 4] grids."""
    arr = np.asarray(observations)
    if arr.ndim == 4 and arr.shape[1:] == (GRID, GRID, NUM_CHANNELS):
        grids = arr
    elif arr.ndim == 3 and arr.shape[1:] == (NUM_CHANNELS, 3):
        grids = compact_to_grid(arr)
    else:
        raise ShapeError(
            f"observations are [T, {GRID}, {GRID}, {NUM_CHANNELS}] grids or [T, {NUM_CHANNELS}, 3] compact "
            f"arrays, got shape {arr.shape}"
        )
    if len(grids) == 0:
        raise ShapeError("need at least one observation to draw a trajectory")
    return grids


def _check_ids(grid: np.ndarray) -> None:
    bad = sorted(int(v) for v in np.unique(grid) if not 0 <= int(v) <= AVATAR_WITH_MESSAGE)
    if bad:
        raise ShapeError(f"observation holds ids that are not Messenger sprites: {bad}")


class _Cell:
    """What one cell shows: its symbol, the identity or avatar id that colours it, what is under it."""

    __slots__ = ("symbol", "colour_key", "hidden")

    def __init__(self, symbol: str, colour_key: str, hidden: list[str]) -> None:
        self.symbol = symbol
        self.colour_key = colour_key  # an identity name, "avatar", "avatar_message", "overlap", "empty"
        self.hidden = hidden  # identities drawn over (under the avatar) or merged into '*'


def _cells(grid: np.ndarray) -> list[list[_Cell]]:
    """The symbol of every cell, applying the overlap rules of the module docstring."""
    _check_ids(grid)
    rows: list[list[_Cell]] = []
    for r in range(GRID):
        row: list[_Cell] = []
        for c in range(GRID):
            # By id, not by channel: an imagined observation may put any sprite in any channel.
            values = [int(v) for v in grid[r, c] if v != 0]
            entities = [ID_TO_IDENTITY[v] for v in values if v in ID_TO_IDENTITY]
            avatar = max((v for v in values if v in (AVATAR_NO_MESSAGE, AVATAR_WITH_MESSAGE)), default=0)
            if avatar == AVATAR_WITH_MESSAGE:
                row.append(_Cell(AVATAR_MESSAGE_LETTER, "avatar_message", entities))
            elif avatar == AVATAR_NO_MESSAGE:
                row.append(_Cell(AVATAR_LETTER, "avatar", entities))
            elif len(entities) > 1:
                row.append(_Cell(OVERLAP_LETTER, "overlap", entities))
            elif entities:
                row.append(_Cell(IDENTITY_LETTERS[entities[0]], entities[0], []))
            elif WALL in values:  # never in the real stage-2 game, but a model can imagine one
                row.append(_Cell(WALL_LETTER, "empty", []))
            elif values:  # an id no sprite has (1): only an imagined observation holds one
                row.append(_Cell(UNKNOWN_LETTER, "empty", []))
            else:
                row.append(_Cell(EMPTY_LETTER, "empty", []))
        rows.append(row)
    return rows


def _ansi(cell: _Cell) -> str:
    if cell.colour_key == "avatar":
        code = _ANSI_AVATAR
    elif cell.colour_key == "avatar_message":
        code = _ANSI_AVATAR_MESSAGE
    elif cell.colour_key == "overlap":
        code = _ANSI_OVERLAP
    elif cell.colour_key == "empty":
        code = _ANSI_EMPTY
    else:
        code = "1;" + _ANSI_IDENTITY[cell.colour_key]
    return f"\x1b[{code}m{cell.symbol}{_ANSI_RESET}"


def _rgb(cell: _Cell) -> tuple[int, int, int]:
    return {
        "avatar": _RGB_AVATAR,
        "avatar_message": _RGB_AVATAR_MESSAGE,
        "overlap": _RGB_OVERLAP,
        "empty": _RGB_EMPTY,
    }.get(cell.colour_key) or _RGB_IDENTITY[cell.colour_key]


# --------------------------------------------------------------------------- text
def render_ascii(obs: np.ndarray, color: bool = False) -> str:
    """The board as text: GRID lines of GRID symbols separated by spaces (cells look square in
    a terminal that way), inside a '+--+' / '|' border. Row r of the board is line r + 1.

    Args:
        obs: one observation, [10, 10, 4] grid or [4, 3] compact.
        color: wrap symbols in ANSI colour codes (only for terminals that understand them).
    Raises:
        ShapeError: for any other shape, or ids that are not Messenger sprites.
    """
    cells = _cells(_as_grid(obs))
    width = 2 * GRID + 1
    lines = ["+" + "-" * width + "+"]
    for row in cells:
        symbols = [_ansi(cell) if color else cell.symbol for cell in row]
        lines.append("| " + " ".join(symbols) + " |")
    lines.append(lines[0])
    return "\n".join(lines)


# What the symbols that are no identity's letter stand for, in the terminal's legend and the page's key.
SYMBOL_WORDS: dict[str, str] = {
    "avatar": "you",
    "avatar_message": "you, carrying the message",
    "overlap": "two entities on one cell",
}
_KEY_SYMBOLS = {"avatar": AVATAR_LETTER, "avatar_message": AVATAR_MESSAGE_LETTER, "overlap": OVERLAP_LETTER}


def symbol_key() -> list[dict]:
    """The board's symbols that are no identity's letter, as a page draws them in its key: symbol,
    colour ("#rrggbb") and what it stands for."""
    colours = {"avatar": _RGB_AVATAR, "avatar_message": _RGB_AVATAR_MESSAGE, "overlap": _RGB_OVERLAP}
    return [
        {"symbol": _KEY_SYMBOLS[key], "colour": _hex(colours[key]), "words": words}
        for key, words in SYMBOL_WORDS.items()
    ]


def legend(obs: np.ndarray, every_avatar: bool = False) -> str:
    """The symbols present on the board, e.g. "D dog  Q queen  L ball  @ you"; overlaps are
    named too ("@ you (on dog)", "* dog+queen") because the board shows one symbol per cell.
    every_avatar: name both avatar symbols ('@' and '&') even when this board shows one, for a
    legend that serves the boards after it too (a plan's later boards may show the other)."""
    cells = [cell for row in _cells(_as_grid(obs)) for cell in row]
    parts: list[str] = []
    seen: set[str] = set()
    # Identities in board order, so the legend reads like the board.
    for cell in cells:
        names = [cell.colour_key] if cell.colour_key in IDENTITY_LETTERS else cell.hidden
        for name in names:
            if name not in seen:
                seen.add(name)
                parts.append(f"{IDENTITY_LETTERS[name]} {name}")
    for cell in cells:
        if cell.colour_key in ("avatar", "avatar_message"):
            what = SYMBOL_WORDS[cell.colour_key]
            if cell.hidden:
                what += " (on " + "+".join(cell.hidden) + ")"
            parts.append(f"{cell.symbol} {what}")
    for cell in cells:
        if cell.colour_key == "overlap":
            parts.append(f"{OVERLAP_LETTER} {'+'.join(cell.hidden)}")
    shown = {cell.colour_key for cell in cells}
    if not shown & {"avatar", "avatar_message"}:
        parts.append("(no avatar)")
    if every_avatar:
        parts += [
            f"{_KEY_SYMBOLS[key]} {SYMBOL_WORDS[key]}" for key in ("avatar", "avatar_message") if key not in shown
        ]
    return "  ".join(parts)


def _hex(rgb: tuple[int, int, int]) -> str:
    return "#" + "".join(f"{v:02x}" for v in rgb)


def identity_style(name: str) -> tuple[str, str]:
    """The letter and colour ("#rrggbb") an identity is drawn with."""
    return IDENTITY_LETTERS[name], _hex(_RGB_IDENTITY[name])


def board(obs: np.ndarray) -> list[dict]:
    """The non-empty cells as the pictures draw them, for a page that draws the board itself:
    row, col, symbol, colour ("#rrggbb") and the identities under the symbol (overlaps)."""
    out = []
    for r, row in enumerate(_cells(_as_grid(obs))):
        for c, cell in enumerate(row):
            if cell.colour_key != "empty" or cell.symbol != EMPTY_LETTER:
                colour = _hex(_rgb(cell))
                out.append({"row": r, "col": c, "symbol": cell.symbol, "colour": colour, "under": cell.hidden})
    return out


# --------------------------------------------------------------------------- images
def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """PIL's default font at roughly `size` pixels (older Pillow has only the fixed bitmap font)."""
    try:
        return ImageFont.load_default(size=max(8, size))
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def _text_colour(bg: tuple[int, int, int]) -> tuple[int, int, int]:
    """Black on light cells, white on dark ones, so letters stay readable on every colour."""
    luminance = 0.299 * bg[0] + 0.587 * bg[1] + 0.114 * bg[2]
    return (0, 0, 0) if luminance > 140 else (255, 255, 255)


def _draw_board(draw: ImageDraw.ImageDraw, grid: np.ndarray, x0: int, y0: int, cell: int) -> None:
    font = _font(int(cell * 0.6))
    for r, row in enumerate(_cells(grid)):
        for c, sprite in enumerate(row):
            box = (x0 + c * cell, y0 + r * cell, x0 + (c + 1) * cell - 1, y0 + (r + 1) * cell - 1)
            bg = _rgb(sprite)
            draw.rectangle(box, fill=bg)
            if sprite.colour_key != "empty":
                centre = (x0 + c * cell + cell / 2, y0 + r * cell + cell / 2)
                draw.text(centre, sprite.symbol, fill=_text_colour(bg), font=font, anchor="mm")
    for k in range(GRID + 1):
        edge = min(k * cell, GRID * cell - 1)
        draw.line([(x0 + edge, y0), (x0 + edge, y0 + GRID * cell - 1)], fill=_RGB_GRID_LINE)
        draw.line([(x0, y0 + edge), (x0 + GRID * cell - 1, y0 + edge)], fill=_RGB_GRID_LINE)


def _check_cell(cell: int) -> None:
    if not isinstance(cell, (int, np.integer)) or cell < 4:
        raise ValueError(f"cell is the size of a board cell in pixels, an integer >= 4, got {cell!r}")


def render_png(obs: np.ndarray, path: str | Path | None = None, cell: int = 32) -> Image.Image:
    """One observation as an RGB image of (10 * cell) x (10 * cell) pixels: a coloured square with
    its letter per sprite, grid lines between cells. Saved to `path` when given."""
    _check_cell(cell)
    grid = _as_grid(obs)
    image = Image.new("RGB", (GRID * cell, GRID * cell), _RGB_EMPTY)
    _draw_board(ImageDraw.Draw(image), grid, 0, 0, cell)
    if path is not None:
        image.save(path)
    return image


def _per_frame(values: Sequence | np.ndarray | None, t: int, name: str) -> list | None:
    """Align actions or rewards with the T frames.

    Both layouts in the project are accepted: T values (value i led to frame i; the first is a
    dummy, as in the dataset and imagination arrays) or T - 1 values (value i led to frame i + 1).
    Returns a list of T entries with None where a frame has no value.
    """
    if values is None:
        return None
    seq = list(np.asarray(values).reshape(-1).tolist())
    if len(seq) == t:
        return [None] + seq[1:]
    if len(seq) == t - 1:
        return [None] + seq
    raise ShapeError(f"{name} must have {t} (the first a dummy) or {t - 1} entries for {t} frames, got {len(seq)}")


def _caption(i: int, actions: list | None, rewards: list | None) -> str:
    if i == 0:
        return "t=0 start"
    parts = [f"t={i}"]
    if actions is not None and actions[i] is not None:
        a = int(actions[i])
        parts.append(ACTION_NAMES[a] if 0 <= a < NUM_ACTIONS else f"a{a}")
    if rewards is not None and rewards[i] is not None:
        parts.append(f"r={float(rewards[i]):+g}")
    return " ".join(parts)


def _frames(
    observations: np.ndarray | Sequence[np.ndarray],
    rewards: Sequence[float] | np.ndarray | None,
    actions: Sequence[int] | np.ndarray | None,
    cell: int,
) -> list[Image.Image]:
    """Each observation as a board with its caption (step, action, reward) underneath."""
    _check_cell(cell)
    grids = _as_grids(observations)
    t = len(grids)
    acts = _per_frame(actions, t, "actions")
    rews = _per_frame(rewards, t, "rewards")
    font = _font(max(10, cell // 2))
    caption_h = max(14, cell // 2 + 6)
    frames = []
    for i, grid in enumerate(grids):
        frame = Image.new("RGB", (GRID * cell, GRID * cell + caption_h), _RGB_CAPTION_BG)
        draw = ImageDraw.Draw(frame)
        _draw_board(draw, grid, 0, 0, cell)
        caption = _caption(i, acts, rews)
        draw.text((4, GRID * cell + caption_h / 2), caption, fill=_RGB_TEXT, font=font, anchor="lm")
        frames.append(frame)
    return frames


def render_trajectory_png(
    observations: np.ndarray | Sequence[np.ndarray],
    path: str | Path | None,
    rewards: Sequence[float] | np.ndarray | None = None,
    actions: Sequence[int] | np.ndarray | None = None,
    cell: int = 24,
    per_row: int = 8,
) -> Image.Image:
    """A trajectory as one image: frames left to right with a caption each ("t=3 right r=+0.5"),
    wrapping after `per_row` frames so a 33-step episode stays viewable. Saved to `path` (if given).

    `actions` and `rewards` may have T entries (the first a dummy) or T - 1 (see `_per_frame`).
    """
    if per_row < 1:
        raise ValueError(f"per_row must be >= 1, got {per_row}")
    frames = _frames(observations, rewards, actions, cell)
    gap = max(4, cell // 4)
    fw, fh = frames[0].size
    cols = min(per_row, len(frames))
    rows = (len(frames) + per_row - 1) // per_row
    sheet = Image.new("RGB", (cols * fw + (cols + 1) * gap, rows * fh + (rows + 1) * gap), _RGB_CAPTION_BG)
    for i, frame in enumerate(frames):
        r, c = divmod(i, per_row)
        sheet.paste(frame, (gap + c * (fw + gap), gap + r * (fh + gap)))
    if path is not None:
        sheet.save(path)
    return sheet


def render_trajectory_gif(
    observations: np.ndarray | Sequence[np.ndarray],
    path: str | Path,
    rewards: Sequence[float] | np.ndarray | None = None,
    actions: Sequence[int] | np.ndarray | None = None,
    cell: int = 32,
    duration_ms: int = 400,
) -> list[Image.Image]:
    """A trajectory as an animated GIF, one captioned frame per observation, looping forever.
    Returns the frames (as RGB images)."""
    if duration_ms < 1:
        raise ValueError(f"duration_ms must be >= 1, got {duration_ms}")
    frames = _frames(observations, rewards, actions, cell)
    # The GIF writer merges identical consecutive frames; the step number in every caption keeps
    # them distinct, so the file has exactly one frame per observation.
    palettised = [f.convert("P", palette=Image.Palette.ADAPTIVE, colors=64) for f in frames]
    palettised[0].save(
        path,
        save_all=True,
        append_images=palettised[1:],
        duration=duration_ms,
        loop=0,
        optimize=False,
        disposal=1,
    )
    return frames

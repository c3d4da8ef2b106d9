"""Edits of a trained avatar as data: a texel mask (one bool per Gaussian: Gaussians are the valid
texels of the UV map) and an operation -- paint seen / unseen, lock, erase, recolour, redo.

``EditList`` (edit_list.py) is what the avatar applies, at the one place between the decoder and
everything that renders or exports (``AvatarState.decode`` / ``posed`` / ``snapshot``);
``EditSession`` (session.py) is what a user works with: a selection, ``apply(op)``, ``undo()`` /
``redo()``, ``entries()``, ``save()``; ``store.py`` reads and writes ``RUN/edits/``. docs/editing.md.
"""

from .edit_list import EditEntry, EditList
from .ops import OPS, Erase, Lock, Op, PaintSeen, PaintUnseen, Recolour, Redo, parse_op
from .store import EDITS_DIR, EDITS_NAME, EditsError, load_edits, save_edits

__all__ = ["EditEntry", "EditList", "OPS", "Erase", "Lock", "Op", "PaintSeen", "PaintUnseen", "Recolour", "Redo",
           "parse_op", "EDITS_DIR", "EDITS_NAME", "EditsError", "load_edits", "save_edits"]

"""The one direction of imports (docs/design_notes.md): training never imports Stage II, the body
package never imports the data package, nothing below the run folder imports it or the app."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def imported_modules(path: Path) -> set[str]:
    """Every module a file imports, anywhere in it (function-level imports too), as absolute names."""
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)
    return out


def offenders(folder: str, forbidden: tuple[str, ...]) -> dict[str, list[str]]:
    found = {}
    for path in sorted((ROOT / folder).rglob("*.py")):
        bad = sorted(m for m in imported_modules(path) if m.startswith(forbidden))
        if bad:
            found[str(path.relative_to(ROOT))] = bad
    return found


def test_the_import_checker_sees_relative_and_function_level_imports(tmp_path):
    assert "reconstruct.stage2.plan" in imported_modules(ROOT / "reconstruct/run_folder.py")
    assert "reconstruct.data.load" in imported_modules(ROOT / "reconstruct/run_folder.py")  # inside a method


def test_training_does_not_import_stage2():
    assert offenders("reconstruct/train", ("reconstruct.stage2",)) == {}


def test_body_does_not_import_data():
    assert offenders("reconstruct/body", ("reconstruct.data",)) == {}


def test_library_does_not_import_the_run_folder_or_the_app():
    for folder in ("reconstruct/train", "reconstruct/stage2", "reconstruct/avatar", "reconstruct/body",
                   "reconstruct/data", "reconstruct/raster", "reconstruct/priors", "reconstruct/metrics"):
        assert offenders(folder, ("reconstruct.run_folder", "app")) == {}, folder


def test_body_backends_do_not_import_the_backend_table():
    """spec.py's table builds the backends; a backend that imported it back would close a circle."""
    for name in ("anny_backend.py", "smpl_backend.py"):
        assert "reconstruct.body.spec" not in imported_modules(ROOT / "reconstruct/body" / name), name

"""docs/architecture.md's layer table holds: every module imports, at module level, only its own layer and
the layers above it, and every module of the package has a row."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def layers() -> dict[str, int]:
    """Module name -> layer index, read from the table (a row without a layer name continues the one above)."""
    index, out = -1, {}
    for line in (ROOT / "docs" / "architecture.md").read_text().splitlines():
        cells = [c.strip() for c in line.split("|")[1:-1]]
        if len(cells) != 3 or cells[0] in ("layer", "---"):
            continue
        if cells[0]:
            index += 1
        for mod in re.findall(r"`mjendo/(\w+)\.py`", cells[1]):
            out[mod] = index
    return out


def module_level_imports(path: Path) -> set[str]:
    """mjendo modules imported outside functions (imports inside a function are a higher layer's tools)."""
    found = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("mjendo"):
            parts = node.module.split(".")
            found |= {parts[1]} if len(parts) > 1 else {a.name for a in node.names}
        elif isinstance(node, ast.Import):
            found |= {a.name.split(".")[1] for a in node.names if a.name.startswith("mjendo.")}
    return found


def test_every_module_has_a_row_and_imports_only_its_layer_and_those_above():
    table = layers()
    modules = {p.stem for p in (ROOT / "mjendo").glob("*.py") if p.stem != "__init__"}
    assert modules == set(table), f"rows missing: {modules - set(table)}; rows without a module: {set(table) - modules}"
    wrong = [(m, dep) for m in sorted(modules) for dep in module_level_imports(ROOT / "mjendo" / f"{m}.py")
             if dep in table and table[dep] > table[m]]
    assert not wrong, f"imports from a lower layer (module, import): {wrong}"

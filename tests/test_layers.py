"""The core's architecture as a test: each package imports only the layers below it, and nothing in
the core imports ROS."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parent.parent / "lwm_models"
# Lowest first. The game knows no text; text and the benchmark data build on the game; the message
# formats, the review ledger and the feedback signatures on those; the world models on all of these;
# the agent on the world models; the command line on everything.
LAYERS = [
    {"errors", "stats", "run_dirs"},
    {"messenger"},
    {"text"},
    {"data"},
    {"messages", "ledger", "signing", "recording"},
    {"world"},
    {"agent"},
    {"cli"},
]
LEVEL = {name: i for i, layer in enumerate(LAYERS) for name in layer}


def imports(source: str, rel: Path) -> list[tuple[str, int]]:
    """(imported top-level unit of lwm_models or an outside module name, line) of the source of
    the file at `rel` inside lwm_models."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level:
            here = list(rel.parts[:-1])
            base = here[: len(here) - (node.level - 1)]
            target = base + (node.module.split(".") if node.module else [])
            names = [target[0]] if target else [alias.name for alias in node.names]  # `from .. import x`
            out += [(name, node.lineno) for name in names]
        elif isinstance(node, ast.ImportFrom):
            out.append((node.module or "", node.lineno))
        elif isinstance(node, ast.Import):
            out += [(alias.name, node.lineno) for alias in node.names]
    return out


def unit_of(path: Path) -> str:
    rel = path.relative_to(CORE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


@pytest.mark.parametrize("path", sorted(CORE.rglob("*.py")), ids=lambda p: str(p.relative_to(CORE)))
def test_imports_go_down_the_layers(path):
    unit = unit_of(path)
    if unit == "__init__":
        return
    assert unit in LEVEL, f"{unit} is in no layer: add it to LAYERS"
    for name, line in imports(path.read_text(), path.relative_to(CORE)):
        if name.startswith(("rclpy", "lwm_nodes", "std_msgs", "lwm_interfaces")):
            pytest.fail(f"{path.name}:{line} imports {name}: the core never imports the ROS layer")
        target = name.split(".")[1] if name.startswith("lwm_models.") else name
        if target in LEVEL and target != unit:
            assert LEVEL[target] < LEVEL[unit], f"{path.name}:{line}: {unit} imports {target}, a layer above it"


def test_the_check_resolves_relative_imports():
    source = "from ..world.base import WorldModel\nfrom .. import agent\nfrom .engine import X\nimport rclpy\n"
    found = {name for name, _ in imports(source, Path("messenger/probe.py"))}
    assert found == {"world", "agent", "messenger", "rclpy"}

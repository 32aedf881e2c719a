"""Each node's YAML parameter file (ros_ws/src/lwm_nodes/config/) documents every parameter the
node declares, no other, and with the default the code declares: a parameter added in code and
forgotten in the file (or the reverse) fails here, not at a user who edits the file."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest
import yaml

NODES = Path(__file__).resolve().parents[1] / "ros_ws" / "src" / "lwm_nodes"
# The modules whose declarations make up each node's parameters; HELPERS are functions (and a
# class, and JsonNode's __init__) of lwm_nodes that declare parameters for the nodes that call them.
CONFIGS = {
    "messenger_env.yaml": ["env_node", "__init__"],
    "lwm_world_model.yaml": [
        "world_model_node",
        "__init__",
        "declare_agents",
        "declare_threads",
        "declare_keyring",
        "_keys_file",
    ],
    "planner.yaml": ["planner_node", "__init__", "declare_threads", "declare_keyring", "_keys_file"],
    "human_feedback.yaml": [
        "human_node",
        "__init__",
        "scripted_reviewer",
        "page_reviewer",
        "terminal_reviewer",
        "Signer",
        "_keys_file",
    ],
    "lwm_recorder.yaml": ["recorder_node", "__init__"],
    "fleet_page.yaml": ["fleet_page_node", "__init__", "Signer", "_keys_file"],
    "live_view.yaml": ["live_view_node", "__init__", "declare_agents"],
}
HELPERS = {
    "__init__": "common",  # JsonNode's: every node's
    "declare_agents": "common",
    "declare_threads": "common",
    "declare_keyring": "trust",
    "Signer": "trust",
    "_keys_file": "trust",
}


def declared(part: str) -> dict[str, object]:
    """Parameter name -> its default (None when it depends on the run) declared by a module, or by
    one helper function or class of a module."""
    module = HELPERS.get(part, part)
    tree = ast.parse((NODES / "lwm_nodes" / f"{module}.py").read_text())
    if part in HELPERS:
        tree = next(n for n in ast.walk(tree) if getattr(n, "name", None) == part)
    found = {}
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)):
            continue
        name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
        if name in ("declare_parameter", "p") and isinstance(node.args[0].value, str):
            default = node.args[1] if len(node.args) > 1 else None
            found[node.args[0].value] = None if default is None else value_of(default, module)
    return found


def value_of(default: ast.expr, module: str) -> object:
    """A declared default's value: a literal, or an attribute of a name the module imports (a
    dataclass field such as Teaching.rounds); None when it depends on the run (a path, a variable)."""
    try:
        return ast.literal_eval(default)
    except ValueError:
        pass
    if isinstance(default, ast.Attribute) and isinstance(default.value, ast.Name):
        pytest.importorskip("rclpy")
        namespace = vars(importlib.import_module(f"lwm_nodes.{module}"))
        return getattr(namespace[default.value.id], default.attr)
    return None


@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_a_nodes_yaml_documents_exactly_its_parameters_with_the_codes_defaults(config):
    text = (NODES / "config" / config).read_text()
    values = yaml.safe_load(text)["/**"]["ros__parameters"]
    # A parameter whose default depends on the run (a path, the kind of reviewer) is documented
    # in a comment, "# name: example", not set.
    commented = set(re.findall(r'^\s*# ([a-z_]+): "', text, re.M))
    code: dict[str, object] = {}
    for part in CONFIGS[config]:
        code.update(declared(part))
    assert set(values) | commented == set(code), f"{config}: documented vs declared differ"
    for name, value in values.items():
        if code[name] is not None:
            assert value == code[name], f"{config}: {name} is {value!r} in the file, {code[name]!r} in the code"

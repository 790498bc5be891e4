"""The type stubs describe the native module as it is: every public name of
Session, Tick and LoopStats and of the module is in _native.pyi, and
nothing more."""

from __future__ import annotations

import ast
from pathlib import Path

import hapticctrl._native as native

STUB = Path(native.__file__).with_name("_native.pyi")


def stub_names() -> tuple[set[str], dict[str, set[str]]]:
    tree = ast.parse(STUB.read_text())
    top: set[str] = set()
    classes: dict[str, set[str]] = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            names = set()
            for item in node.body:
                if isinstance(item, ast.FunctionDef):
                    names.add(item.name)
                elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    names.add(item.target.id)
            classes[node.name] = {n for n in names if not n.startswith("_")}
            top.add(node.name)
        elif isinstance(node, ast.FunctionDef):
            top.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            top.add(node.target.id)
    return top, classes


def test_the_stubs_match_the_module():
    top, classes = stub_names()
    runtime = {n for n in dir(native) if not n.startswith("_")}
    assert runtime <= top, f"missing from the stubs: {runtime - top}"
    for cls in ("Session", "Tick", "LoopStats"):
        have = {n for n in dir(getattr(native, cls)) if not n.startswith("_")}
        assert have == classes[cls], (cls, have ^ classes[cls])

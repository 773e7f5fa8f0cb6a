"""The type stubs (hetcomm/_hetcomm.pyi) and py.typed ship in the wheel and name every public
class, method and function of the native module."""

from __future__ import annotations

import ast
from pathlib import Path

import hetcomm
from hetcomm import _hetcomm

PKG = Path(hetcomm.__file__).parent


def stub_names():
    tree = ast.parse((PKG / "_hetcomm.pyi").read_text())
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            out[node.name] = {n.name for n in node.body if isinstance(n, ast.FunctionDef)}
        elif isinstance(node, ast.FunctionDef):
            out[node.name] = None
    return out


def test_stubs_and_marker_are_installed():
    assert (PKG / "py.typed").exists()
    assert (PKG / "_hetcomm.pyi").exists()


def test_stubs_cover_the_native_module():
    stubs = stub_names()
    for name in dir(_hetcomm):
        if name.startswith("_"):
            continue
        obj = getattr(_hetcomm, name)
        assert name in stubs, f"{name} has no stub"
        if isinstance(obj, type):
            public = {m for m in vars(obj) if not m.startswith("_")}
            assert public <= stubs[name], f"{name}: no stub for {sorted(public - stubs[name])}"


def test_package_exports():
    for name in hetcomm.__all__:
        assert hasattr(hetcomm, name), name

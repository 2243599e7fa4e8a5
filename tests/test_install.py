"""The install is right: torchrl's C++ extension loads against the pinned torch."""

import importlib


def test_torchrl_cpp_extension_imports():
    ext = importlib.import_module("torchrl._torchrl")
    assert hasattr(ext, "SumSegmentTreeFp32")  # the prioritized sampler's sum tree


def test_pinned_versions():
    import torch
    import torchrl

    assert torch.__version__.split("+")[0] == "2.14.1"
    assert torchrl.__version__.startswith("0.14.1")

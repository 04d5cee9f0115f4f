"""README.md's Python blocks run as printed, top to bottom in one namespace, and print true values."""

import re
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_readme_blocks_run_in_order(tmp_path, monkeypatch):
    assert len(BLOCKS) >= 3
    monkeypatch.chdir(tmp_path)  # blocks that save files write here
    monkeypatch.setenv("PYFREP_VIEW", "image")  # no kernel: the 3-D view is an off-screen image
    ns: dict = {}
    for index, block in enumerate(BLOCKS):
        exec(compile(block, f"README.md python block {index}", "exec"), ns)
        if index == 0:  # the Fig. 1 program meshed at 128^3: the count and volume its comment prints
            assert ns["mesh"].n_faces == 104_656
            assert ns["mesh"].volume() == pytest.approx(0.9868, abs=5e-5)
            assert abs(ns["mesh"].volume() - 0.98879) < 3e-3
    # the values the README's comments promise
    assert ns["mesh"].n_vertices > 0 and (tmp_path / "sphere.ply").exists()
    assert np.abs(ns["c"].H - 2.0).max() < 1e-9 and np.abs(ns["c"].K - 4.0).max() < 1e-9
    assert ns["part"](ns["x"], r=ns["torch"].tensor([0.3, 0.4, 0.5])).shape == (3, 1000)
    # the paper-style model: 4/3 pi to within (h / r)^2 of a cell h = 2.4 / 47 (marching cubes' chords), two sets
    assert ns["ball_mesh"].volume() == pytest.approx(4 / 3 * np.pi, rel=(2.4 / 47) ** 2)
    sets = ns["paper_ball"](ns["torch"].zeros(2, 3), r=ns["torch"].tensor([0.6, 0.8]))
    np.testing.assert_allclose(sets.numpy(), [[0.36, 0.36], [0.64, 0.64]], rtol=1e-6)  # r^2 in float32
    for name, value in ns["truth"].items():
        assert ns["result"].params[name] == pytest.approx(value, rel=1e-3)
    assert ns["err"].mean < 2e-2
    k = ns["k"]
    assert k.defined.tolist() == [False, True] and np.isnan(k.H[0]) and k.H[1] == pytest.approx(2.0)
    # the compiled Fig. 1 part meshes to the eager program's mesh (block 0)
    assert ns["fast_mesh"].n_faces == 104_656 and ns["fast"].failure is None
    assert ns["fast_mesh"].volume() == pytest.approx(0.9868, abs=5e-5)
    # push-pull: the hole's radius follows the pulled wall
    assert ns["pulled"].change["r"] == pytest.approx(-0.05, abs=1e-6) and ns["pulled"].converged
    # dual contouring: the Fig. 1 part's closed-form volume 0.9887887 within 1e-4 (marching cubes: 2e-3 off)
    assert abs(ns["sharp"].volume() - 0.9887887) < 1e-4 < abs(ns["fast_mesh"].volume() - 0.9887887)
    assert ns["hi"][0] < 0  # the corner box is proved outside
    assert set(ns["grid"].array_names) >= {"f", "grad_norm", "omega1"} and ns["grid"].n_points == 32**3
    # the free-form fit of the sphere: Chamfer under 1 % of its size (the bound), from 4,000 points
    assert ns["gap"].chamfer < 0.01 and ns["gap"].hausdorff < 0.05

"""environment.yml and pyproject.toml list the same dependencies; the two commands are wired."""

import os
import re
import subprocess
import tomllib
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _name(requirement: str) -> str:
    return re.split(r"[<>=!~\[ ;]", requirement.strip(), maxsplit=1)[0].lower().replace("_", "-")


def test_environment_yml_matches_pyproject():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {_name(r) for r in project["dependencies"]}
    declared |= {_name(r) for r in project["optional-dependencies"]["dev"]}
    env = yaml.safe_load((ROOT / "environment.yml").read_text())
    pip_list = next(d["pip"] for d in env["dependencies"] if isinstance(d, dict))
    listed = {_name(r) for r in pip_list if not r.startswith("-e")}
    assert listed == declared, f"only in environment.yml: {listed - declared}; only in pyproject: {declared - listed}"


def test_torch_is_pinned_to_the_cpu_build_everywhere():
    assert "torch==2.13.0" in (ROOT / "constraints.txt").read_text().split()
    assert "torch==2.13.0" in (ROOT / "environment.yml").read_text()


def test_ci_runs_make_test_and_readme_shows_both_commands():
    assert "make test" in (ROOT / ".ci" / "run").read_text()
    readme = (ROOT / "README.md").read_text()
    assert "make run" in readme and "make test" in readme


def _fake_venv(tmp_path):
    """A venv whose install stamp is current and whose voila/pytest/ruff only print PYFREP_QUICK."""
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    for tool in ("voila", "pytest", "ruff", "python"):
        script = venv / "bin" / tool
        script.write_text('#!/bin/sh\necho "PYFREP_QUICK=[${PYFREP_QUICK}]"\n')
        script.chmod(0o755)
    (venv / ".installed").touch()
    return venv


def test_make_run_gives_users_the_full_settings_and_make_test_the_quick_ones(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "PYFREP_QUICK"}
    venv = _fake_venv(tmp_path)

    def quick_mode(target):
        out = subprocess.run(
            ["make", "-s", "-C", str(ROOT), target, f"VENV={venv}"],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        ).stdout
        return set(re.findall(r"PYFREP_QUICK=\[(\d*)\]", out))

    assert quick_mode("run") == {""}
    assert quick_mode("lint") == {""}
    assert quick_mode("test") == {"1"}

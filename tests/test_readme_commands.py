"""Every command of the README works as pasted (issue 50: after `make demo`, later
commands failed in a new shell). Read from README.md's ```bash blocks (and its inline
`python benchmarks/...`, `python docs/...` commands):

* every `zcomp` command names a real command and only options it has (cheap: no run);
* every `python SCRIPT` names a script that exists;
* the commands whose inputs exist after `make demo` (the shipped example, out/demo) run
  for real, each in a new shell that only sources `.venv/bin/activate` as the README says,
  in a copy of the repository (slow: Blender renders the previews)."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from zcomp_cli.cli import cli

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
# Upper bound for one command of the README run for real (the demo: five jobs).
RUN_BOUND_S = 1800


def readme_commands(text: str) -> list[list[str]]:
    """The README's commands as argument lists: each line of a ```bash block
    (continuations joined, comments and optional [...] parts dropped, `a && b` split),
    and inline `python benchmarks/...` / `python docs/...` spans."""
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        lines += block.replace("\\\n", " ").splitlines()
    lines += re.findall(r"`(python (?:benchmarks|docs)/[^`]*)`", text)
    out = []
    for line in lines:
        line = re.sub(r"\[[^\]]*\]", " ", line)
        for part in line.split("&&"):
            args = shlex.split(part, comments=True)
            if args:
                out.append(args)
    return out


COMMANDS = readme_commands(README.read_text())


def _subcommand(args: list[str]) -> list[str]:
    words = [a for a in args[1:] if not a.startswith("-")]
    return words[:2] if words and words[0] == "import" else words[:1]


def test_the_readme_has_the_commands_it_shows():
    zc = [a for a in COMMANDS if a[0] == "zcomp"]
    assert len(zc) > 20 and any(a[0] == "python" for a in COMMANDS)
    assert ["make", "demo"] in COMMANDS and [".", ".venv/bin/activate"] in COMMANDS


@pytest.mark.parametrize("args", [a for a in COMMANDS if a[0] == "zcomp"], ids=lambda a: " ".join(a)[:60])
def test_each_zcomp_command_and_option_exists(args):
    sub = _subcommand(args)
    r = CliRunner().invoke(cli, [*sub, "--help"])
    assert r.exit_code == 0, f"zcomp {' '.join(sub)}: {r.output}"
    for a in args[1:]:
        if a.startswith("--"):
            assert re.search(rf"(^|[\s,/]){re.escape(a.split('=')[0])}([\s,=/]|$)", r.output, re.M), \
                f"zcomp {' '.join(sub)} has no option {a}"


@pytest.mark.parametrize("args", [a for a in COMMANDS if a[0] == "python"], ids=lambda a: " ".join(a)[:60])
def test_each_python_script_exists(args):
    assert (ROOT / args[1]).is_file(), args


def _runnable(args: list[str], root: Path) -> bool:
    """A command whose every input (a positional argument naming a path) is there; not a
    benchmark (minutes each: their scripts are checked to exist)."""
    if args[0] not in ("zcomp", "python") or (args[0] == "python" and args[1].startswith("benchmarks/")):
        return False
    if any(re.fullmatch(r"[A-Z][A-Z0-9_]+", a) for a in args):  # a placeholder (PRED_DIR, CKPT)
        return False
    paths = [a for a in args[1:] if ("/" in a or "." in a) and not a.startswith("-") and not re.fullmatch(
        r"[\d.,-]+", a)]
    outs = {args[i + 1] for i, a in enumerate(args[:-1]) if a == "--out"}
    return all((root / p).exists() for p in paths if p not in outs and not p.startswith("out/example"))


@pytest.mark.slow
@pytest.mark.blender
def test_the_commands_run_as_pasted_in_a_new_shell(tmp_path):
    """In a copy of the repository, as after `make demo`: the demo's composite, then each
    README command whose inputs exist, each in a new shell that sources the venv's
    activate script; exit 0 and no traceback."""
    venv = Path(sys.executable).parent.parent
    if not (venv / "bin" / "activate").is_file():
        pytest.skip("not run from a virtual environment (make test makes .venv)")
    copy = tmp_path / "repo"
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    for f in files:
        (copy / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, copy / f)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = "/usr/local/bin:/usr/bin:/bin"  # a new shell: nothing of the venv until activate

    def sh(cmd: str) -> subprocess.CompletedProcess:
        r = subprocess.run(["bash", "-c", f". {shlex.quote(str(venv / 'bin' / 'activate'))} && {cmd}"],
                           cwd=copy, env=env, capture_output=True, text=True, timeout=RUN_BOUND_S)
        assert r.returncode == 0 and "Traceback" not in r.stderr, f"{cmd}:\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
        return r

    sh("zcomp -q composite examples/jobs.yaml --out out/demo --overwrite")  # what make demo runs
    ran = []
    for args in COMMANDS:
        if _runnable(args, copy):
            sh(shlex.join(args))
            ran.append(args)
    said = {" ".join(a[:2]) for a in ran}
    assert {"zcomp preview-light", "zcomp composite", "zcomp eval", "python docs/make_figures.py"} <= said, said
    assert (copy / "out/demo/preview/room.png").is_file() and (copy / "out/example/summary.json").is_file()

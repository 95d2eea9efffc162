"""The product surface: number checks at the CLI and in YAML, help texts,
the version, the unknown-world message, and the kernel cache directory."""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
from pathlib import Path

import pytest

from topodrake import jitcache, validate
from topodrake.apps import argtypes
from topodrake.apps.cli import build_parser, main
from topodrake.errors import TopodrakeError

ROOT = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------- checks

@pytest.mark.parametrize("check, good, bad", [
    (validate.check_nonnegative, [0, 0.33, 5], [-1, -1e-9, math.nan, math.inf, "x", True]),
    (validate.check_positive, [1e-6, 3], [0, -2, math.inf]),
    (validate.check_probability, [0.01, 0.99], [0, 1, 1.5, -0.1, math.nan]),
    (validate.check_fraction, [0, 0.5, 1], [-0.01, 1.01]),
    (validate.check_count, [1, 7, 3.0], [0, -3, 1.5, "2"]),
    (validate.check_seed, [0, 2 ** 32 - 1], [-1, 2 ** 32, 0.5]),
])
def test_checks_accept_and_refuse(check, good, bad):
    for v in good:
        check("x", v)
    for v in bad:
        with pytest.raises(TopodrakeError, match=r"^x must be "):
            check("x", v)


def test_check_message_names_setting_and_range():
    with pytest.raises(TopodrakeError) as e:
        validate.check_probability("p_sparsify", 1.5)
    assert str(e.value) == "p_sparsify must be a probability in (0, 1), got 1.5"


# ---------------------------------------------------------------- command line

@pytest.mark.parametrize("argv, option, allowed", [
    (["demo", "--noise", "-1"], "--noise", ">= 0"),
    (["demo", "--noise", "inf"], "--noise", ">= 0"),
    (["trials", "--trials", "0"], "--trials", ">= 1"),
    (["trials", "--seed", "-4"], "--seed", "[0, 4294967295]"),
    (["collect", "w", "--out", "o", "--count", "2.5"], "--count", ">= 1"),
    (["sparsify", "w", "--reach", "r", "--controller", "c", "--p", "1"], "--p", "(0, 1)"),
    (["train", "waypoint", "--config", "c", "--out", "o", "--max-minutes", "-5"],
     "--max-minutes", "> 0"),
])
def test_bad_numbers_exit_2_with_one_line(argv, option, allowed, capsys):
    try:
        code = main(argv)                   # refused by the command
    except SystemExit as e:                 # refused by the option's type
        code = e.code
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and len(err) <= 200
    assert option in err and allowed in err


def test_unknown_world_is_short_and_suggests(capsys):
    assert main(["world", "info", "no-such-world"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and len(err) <= 200
    assert "topodrake world list" in err and "train-00" not in err
    assert main(["world", "info", "test-7"]) == 2
    err = capsys.readouterr().err
    assert "test-0" in err and len(err) <= 200


def test_version(capsys):
    from topodrake import __version__

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"topodrake {__version__}"


def _parsers(parser: argparse.ArgumentParser, path: str = "topodrake"):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{path} {name}")


def _check_help(path: str, parser: argparse.ArgumentParser) -> None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            assert all(helps.get(n) for n in action.choices), f"{path}: a command has no help"
            continue
        assert action.help, f"{path} {action.option_strings or action.dest}: no help"
    text = " ".join(parser.format_help().split())
    assert "``" not in text and ":mod:" not in text and ":func:" not in text, path
    for action in parser._actions:
        if action.option_strings and action.default not in (None, False, argparse.SUPPRESS) \
                and action.nargs != 0:
            bare = "".join(text.split())      # long defaults wrap mid-word
            assert f"(default:{action.default})".replace(" ", "") in bare \
                or "default" in action.help, \
                f"{path} {action.option_strings[0]}: default not shown"


def test_every_command_and_option_has_plain_help():
    paths = []
    for path, parser in _parsers(build_parser()):
        _check_help(path, parser)
        paths.append(path)
    assert "topodrake world info" in paths and "topodrake bench expert" in paths


class _Captured(Exception):
    def __init__(self, parser):
        self.parser = parser


@pytest.mark.parametrize("script", sorted(p.name for p in (ROOT / "studies").glob("*.py")))
def test_study_options_have_help_and_checks(script, monkeypatch):
    spec = importlib.util.spec_from_file_location(f"study_{script[:-3]}", ROOT / "studies" / script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)

    def capture(self, *args, **kwargs):
        raise _Captured(self)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", capture)
    monkeypatch.setattr("sys.argv", [script])
    with pytest.raises(_Captured) as e:
        module.main()
    parser = e.value.parser
    _check_help(script, parser)
    for action in parser._actions:
        if action.dest in ("seed", "noise"):
            assert action.type in (argtypes.seed, argtypes.nonnegative), (script, action.dest)


def test_plain_strips_rest_markup():
    assert argtypes.plain("The ``topodrake`` CLI, see :mod:`topodrake.errors` and "
                          ":func:`~a.b`") == "The topodrake CLI, see topodrake.errors and a.b"


# ---------------------------------------------------------------- YAML

def test_scenario_yaml_numbers_are_checked(tmp_path):
    from topodrake.systems.scenario import Scenario, load_scenario

    bad = tmp_path / "bad.yaml"
    for text, field in (("noise_std: -0.5", "noise_std"), ("t_max_s: .nan", "t_max_s"),
                        ("vehicle: {dt: 0}", "vehicle.dt"), ("goal_place: -1", "goal_place"),
                        ("seed: -3", "seed")):
        bad.write_text(f"world: test-0\n{text}\n")
        with pytest.raises(TopodrakeError, match=rf"^scenario {bad}: {field} must be"):
            load_scenario(bad)
    with pytest.raises(TopodrakeError, match="noise_std"):
        Scenario(noise_std=-1.0)
    good = tmp_path / "good.yaml"
    good.write_text("world: test-0\nnoise_std: 0.2\nseed: 4\n")
    assert load_scenario(good).noise_std == 0.2


def test_train_config_numbers_are_checked(tmp_path):
    from topodrake.learning.config import load_train_config

    bad = tmp_path / "train.yaml"
    bad.write_text("lr: .inf\n")
    with pytest.raises(TopodrakeError, match="lr must be a finite number > 0"):
        load_train_config(bad)
    bad.write_text("data: {samples: {min_overlap: 1.5}}\n")
    with pytest.raises(TopodrakeError, match=r"data.samples.min_overlap must be a number in \[0, 1\]"):
        load_train_config(bad)


# ---------------------------------------------------------------- kernel cache

def test_cache_key_follows_kernel_sources(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "consts.py").write_text("K = 1\n")
    (pkg / "kern.py").write_text("from topodrake.sub.consts import K\n\n@nb.njit(cache=True)\n"
                                 "def f():\n    return K\n")
    (pkg / "other.py").write_text("X = 1\n")
    names = [p.relative_to(pkg).as_posix() for p in jitcache.kernel_sources(pkg)]
    assert names == ["kern.py", "sub/consts.py"]
    key = jitcache.source_key(pkg)
    (pkg / "other.py").write_text("X = 2\n")
    assert jitcache.source_key(pkg) == key           # not a kernel's dependency
    (pkg / "sub" / "consts.py").write_text("K = 2\n")
    assert jitcache.source_key(pkg) != key           # a constant a kernel reads


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0,
                    reason="root writes into read-only folders")
def test_cache_dir_falls_back_when_read_only(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        path = jitcache.choose_cache_dir([locked, tmp_path / "fallback"], key="k")
    finally:
        locked.chmod(0o700)
    assert path == tmp_path / "fallback" / "numba" / "k"


def test_cache_dir_skips_unwritable_base(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    path = jitcache.choose_cache_dir([blocker / "below", tmp_path / "ok"], key="k")
    assert path == tmp_path / "ok" / "numba" / "k" and path.is_dir()
    assert jitcache.choose_cache_dir([blocker / "below"], key="k") is None


def test_kernels_use_the_keyed_cache():
    import numba

    if not os.environ.get("NUMBA_CACHE_DIR"):
        assert Path(numba.config.CACHE_DIR).name == jitcache.source_key()
    from topodrake.expert import kernel

    assert kernel._expert._cache is not None and kernel._expert._cache.__class__.__name__ \
        == "FunctionCache"


# ---------------------------------------------------------------- packaging

def _build_backend():
    spec = importlib.util.spec_from_file_location(
        "topodrake_build", ROOT / "build_backend" / "topodrake_build.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_build_backend_refuses_unsupported_python_in_one_line():
    backend = _build_backend()
    spec = backend.requires_python()
    assert spec and "<" in spec                   # an upper bound is stated
    import platform

    backend.check_python(platform.python_version())   # the running Python is supported
    with pytest.raises(SystemExit) as e:
        backend.check_python("3.99.0")
    message = str(e.value.code)
    assert "\n" not in message and spec in message and "3.99.0" in message
    for hook in ("get_requires_for_build_wheel", "get_requires_for_build_editable",
                 "prepare_metadata_for_build_wheel", "build_wheel", "build_editable",
                 "build_sdist"):
        assert callable(getattr(backend, hook))


# ---------------------------------------------------------------- start-up

def test_first_run_warms_up_without_changing_the_drive():
    """The first run of a runner warms the kernels up on a copy of its start
    and reports it once as startup_s; the drive is the one a warm runner
    makes with the same seed."""
    import numpy as np

    from topodrake.systems.diagram import build_expert_diagram
    from topodrake.systems.run import ExpertRunner
    from topodrake.systems.scenario import Scenario
    from topodrake.world import load_world

    world = load_world("test-0")
    runner = ExpertRunner(build_expert_diagram(
        Scenario(world="test-0", noise_std=0.33, t_max_s=6.0, camera_enabled=False), world=world))
    first = runner.run(seed=3)
    second = runner.run(seed=3)
    assert first.startup_s > 0 and second.startup_s == 0
    assert "startup_s" in first.summary()
    assert np.array_equal(first.poses, second.poses) and np.array_equal(first.noise, second.noise)
    assert first.poses.shape[0] == 62       # 10 Hz log over 0..6 s and the final state

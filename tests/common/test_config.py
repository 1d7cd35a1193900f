"""Tests of common.config: strict YAML -> frozen dataclass loading, overrides and round trips."""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import pytest
import yaml

from common.config import (
    ConfigError,
    apply_overrides,
    atomic_output,
    from_dict,
    load_config,
    save_config,
    to_dict,
)


@dataclass(frozen=True)
class TrainCfg:
    batch_size: int = 32
    lr: float = 3e-4
    optimizer: Literal["adam", "sgd"] = "adam"
    clip: float | None = None
    hidden: tuple[int, ...] = (256, 256)
    use_amp: bool = False

    def __post_init__(self) -> None:
        if self.batch_size <= 0:
            raise ValueError(f"batch_size must be > 0, got {self.batch_size}")


@dataclass(frozen=True)
class EnvCfg:
    character: str = "humanoid"
    num_envs: int = 4
    dt: float = 1 / 30


@dataclass(frozen=True)
class RunCfg:
    name: str
    seed: int = 0
    train: TrainCfg = field(default_factory=TrainCfg)
    env: EnvCfg = field(default_factory=EnvCfg)
    out: Path | None = None


def _write(tmp_path: Path, text: str, name: str = "x.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_load_nested_sections_and_defaults(tmp_path: Path) -> None:
    path = _write(tmp_path, "name: walk\ntrain:\n  batch_size: 64\n  hidden: [128, 64, 32]\nenv:\n  num_envs: 8\n")
    cfg = load_config(RunCfg, path)
    assert cfg == RunCfg(name="walk", train=TrainCfg(batch_size=64, hidden=(128, 64, 32)), env=EnvCfg(num_envs=8))
    assert cfg.train.lr == 3e-4 and cfg.env.character == "humanoid"
    assert isinstance(cfg.train.hidden, tuple)


def test_round_trip_through_save_and_load(tmp_path: Path) -> None:
    cfg = RunCfg(
        name="run",
        seed=7,
        train=TrainCfg(batch_size=16, lr=1e-10, optimizer="sgd", clip=0.5, hidden=(3,), use_amp=True),
        env=EnvCfg(character="amp", dt=0.0125),
        out=Path("runs/a"),
    )
    path = tmp_path / "sub" / "config.yaml"
    save_config(cfg, path)
    assert load_config(RunCfg, path) == cfg
    assert yaml.safe_load(path.read_text())["train"]["hidden"] == [3]
    # Atomic write leaves only the destination file behind.
    assert os.listdir(path.parent) == ["config.yaml"]


def test_to_dict_is_plain_yaml_safe() -> None:
    data = to_dict(RunCfg(name="n", out=Path("o")))
    assert data["train"] == {
        "batch_size": 32,
        "lr": 3e-4,
        "optimizer": "adam",
        "clip": None,
        "hidden": [256, 256],
        "use_amp": False,
    }
    assert data["out"] == "o"
    assert from_dict(RunCfg, yaml.safe_load(yaml.safe_dump(data))) == RunCfg(name="n", out=Path("o"))


def test_unknown_key_top_level_names_file_and_allowed_keys(tmp_path: Path) -> None:
    path = _write(tmp_path, "name: a\nsed: 3\n")
    with pytest.raises(ConfigError) as info:
        load_config(RunCfg, path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: unknown key 'sed'")
    assert "(allowed: env, name, out, seed, train)" in msg


def test_unknown_key_nested_gives_dotted_path(tmp_path: Path) -> None:
    path = _write(tmp_path, "name: a\ntrain:\n  lrr: 0.1\n")
    with pytest.raises(ConfigError, match=r"x\.yaml: unknown key 'train\.lrr' \(allowed: batch_size, clip, hidden"):
        load_config(RunCfg, path)


def test_missing_required_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"x\.yaml: missing required key 'name'"):
        load_config(RunCfg, _write(tmp_path, "seed: 1\n"))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("train: {batch_size: '32'}", r"key 'train\.batch_size' expects int, got '32' \(str\)"),
        ("train: {use_amp: 1}", r"key 'train\.use_amp' expects bool, got 1 \(int\)"),
        ("train: {batch_size: true}", r"key 'train\.batch_size' expects int, got True \(bool\)"),
        ("train: {hidden: [1, x]}", r"key 'train\.hidden\[1\]' expects int, got 'x' \(str\)"),
        ("train: {hidden: 5}", r"key 'train\.hidden' expects tuple\[int, \.\.\.\], got 5 \(int\)"),
        ("train: 3", r"key 'train' expects a mapping \(TrainCfg\), got 3 \(int\)"),
    ],
)
def test_wrong_type_reports_path_expected_type_and_value(tmp_path: Path, text: str, expected: str) -> None:
    path = _write(tmp_path, f"name: a\n{text}\n")
    with pytest.raises(ConfigError, match=expected) as info:
        load_config(RunCfg, path)
    assert str(info.value).startswith(str(path))


def test_int_accepted_for_float_and_converted() -> None:
    cfg = from_dict(RunCfg, {"name": "a", "train": {"lr": 2}, "env": {"dt": 0}})
    assert cfg.train.lr == 2.0 and type(cfg.train.lr) is float
    assert type(cfg.env.dt) is float


def test_yaml_exponent_without_dot_is_a_float(tmp_path: Path) -> None:
    # Plain PyYAML (YAML 1.1) reads '1e-3' as a string; configs must read it as a float.
    cfg = load_config(RunCfg, _write(tmp_path, "name: a\ntrain: {lr: 1e-3}\n"))
    assert cfg.train.lr == 0.001


def test_literal_accepts_members_and_rejects_others() -> None:
    assert from_dict(RunCfg, {"name": "a", "train": {"optimizer": "sgd"}}).train.optimizer == "sgd"
    with pytest.raises(ConfigError, match=r"key 'train\.optimizer' expects Literal\['adam', 'sgd'\], got 'rmsprop'"):
        from_dict(RunCfg, {"name": "a", "train": {"optimizer": "rmsprop"}}, source="cfg.yaml")


def test_optional_accepts_none_and_inner_type() -> None:
    assert from_dict(RunCfg, {"name": "a", "train": {"clip": None}}).train.clip is None
    assert from_dict(RunCfg, {"name": "a", "train": {"clip": 1}}).train.clip == 1.0
    assert from_dict(RunCfg, {"name": "a", "out": "runs/x"}).out == Path("runs/x")
    with pytest.raises(ConfigError, match=r"key 'train\.clip' expects float \| None, got 'big' \(str\)"):
        from_dict(RunCfg, {"name": "a", "train": {"clip": "big"}})


def test_post_init_error_is_wrapped_with_file_and_section(tmp_path: Path) -> None:
    path = _write(tmp_path, "name: a\ntrain: {batch_size: 0}\n")
    with pytest.raises(ConfigError) as info:
        load_config(RunCfg, path)
    assert str(info.value) == f"{path}: invalid section 'train': batch_size must be > 0, got 0"
    assert isinstance(info.value, ValueError)


def test_overrides_are_parsed_as_yaml(tmp_path: Path) -> None:
    path = _write(tmp_path, "name: a\ntrain: {batch_size: 8}\n")
    cfg = load_config(
        RunCfg,
        path,
        ["train.batch_size=3", "train.lr=1e-3", "seed=5", "env.character=amp", "train.hidden=[4, 5]", "out=null"],
    )
    assert cfg.train.batch_size == 3 and cfg.train.lr == 0.001 and cfg.seed == 5
    assert cfg.env.character == "amp" and cfg.train.hidden == (4, 5) and cfg.out is None


def test_override_value_may_contain_equals_sign() -> None:
    assert apply_overrides(RunCfg, {"name": "a"}, ["name=a=b"]) == {"name": "a=b"}


def test_override_fills_section_missing_from_file(tmp_path: Path) -> None:
    cfg = load_config(RunCfg, _write(tmp_path, "name: a\n"), ["env.num_envs=2"])
    assert cfg.env == EnvCfg(num_envs=2)


def test_overrides_do_not_modify_input() -> None:
    data = {"name": "a", "train": {"batch_size": 8}}
    assert apply_overrides(RunCfg, data, ["train.batch_size=9"])["train"]["batch_size"] == 9
    assert data["train"]["batch_size"] == 8


@pytest.mark.parametrize("override", ["train.batch_size", "=3", "train..lr=1"])
def test_malformed_override_raises(tmp_path: Path, override: str) -> None:
    with pytest.raises(ConfigError, match="expected 'section.key=value'"):
        load_config(RunCfg, _write(tmp_path, "name: a\n"), [override])


def test_override_of_unknown_key_raises(tmp_path: Path) -> None:
    path = _write(tmp_path, "name: a\n")
    with pytest.raises(ConfigError, match=r"override 'train\.lrr=1': unknown key 'train\.lrr' \(allowed: batch_size"):
        load_config(RunCfg, path, ["train.lrr=1"])
    with pytest.raises(ConfigError, match=r"'seed' is not a section"):
        load_config(RunCfg, path, ["seed.x=1"])


def test_override_with_wrong_type_names_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"key 'train\.batch_size' expects int, got 'many' \(str\)"):
        load_config(RunCfg, _write(tmp_path, "name: a\n"), ["train.batch_size=many"])


def test_empty_file_and_non_mapping_file(tmp_path: Path) -> None:
    @dataclass(frozen=True)
    class AllDefaults:
        x: int = 1

    assert load_config(AllDefaults, _write(tmp_path, "", "empty.yaml")) == AllDefaults()
    with pytest.raises(ConfigError, match=r"list\.yaml: top level must be a mapping, got list"):
        load_config(AllDefaults, _write(tmp_path, "- 1\n", "list.yaml"))


def test_from_dict_requires_dataclass_type() -> None:
    with pytest.raises(TypeError):
        from_dict(dict, {})
    with pytest.raises(TypeError):
        to_dict(RunCfg)
    assert from_dict(EnvCfg, {}) == EnvCfg()


def test_a_base_file_supplies_what_the_config_does_not_name(tmp_path: Path) -> None:
    _write(tmp_path, "name: walk\nseed: 3\ntrain:\n  batch_size: 64\n  hidden: [8, 8]\nenv:\n  num_envs: 8\n", "b.yaml")
    sub = tmp_path / "exp"
    sub.mkdir()
    path = _write(sub, "base: ../b.yaml\ntrain:\n  lr: 0.5\n  hidden: [4]\n")
    cfg = load_config(RunCfg, path, ["env.dt=0.02"])
    # Sections merge key by key (train keeps the base's batch_size), lists and scalars replace, overrides come last.
    assert cfg == RunCfg(name="walk", seed=3, train=TrainCfg(batch_size=64, lr=0.5, hidden=(4,)),
                         env=EnvCfg(num_envs=8, dt=0.02))  # fmt: skip
    # A chain of bases: the nearest wins.
    top = _write(sub, "base: x.yaml\nseed: 9\n", "top.yaml")
    assert load_config(RunCfg, top) == replace(cfg, seed=9, env=EnvCfg(num_envs=8))


def test_a_bad_base_is_refused_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"x\.yaml: 'base: nosuch.yaml': no such file"):
        load_config(RunCfg, _write(tmp_path, "base: nosuch.yaml\nname: a\n"))
    with pytest.raises(ConfigError, match=r"'base' must be the path of another config file, got 3"):
        load_config(RunCfg, _write(tmp_path, "base: 3\nname: a\n"))
    _write(tmp_path, "base: b.yaml\nname: a\n", "a.yaml")
    with pytest.raises(ConfigError, match="makes a cycle of base files"):
        load_config(RunCfg, _write(tmp_path, "base: a.yaml\n", "b.yaml"))
    # An unknown key in the base is still refused.
    _write(tmp_path, "name: a\nsed: 1\n", "c.yaml")
    with pytest.raises(ConfigError, match="unknown key 'sed'"):
        load_config(RunCfg, _write(tmp_path, "base: c.yaml\n", "d.yaml"))


def test_atomic_output_gives_the_mode_open_would(tmp_path: Path) -> None:
    """mkstemp makes its file 0o600; the written file must get 0o666 less the umask, as ``open`` gives a new file,
    and a file written again keeps its own mode. A failed block leaves the old content and no temporary file."""
    umask = os.umask(0o022)
    os.umask(umask)
    new = tmp_path / "new.txt"
    with atomic_output(new) as tmp:
        tmp.write_text("a")
    assert stat.S_IMODE(new.stat().st_mode) == 0o666 & ~umask
    new.chmod(0o640)
    with atomic_output(new) as tmp:
        tmp.write_text("b")
    assert stat.S_IMODE(new.stat().st_mode) == 0o640 and new.read_text() == "b"
    with pytest.raises(RuntimeError), atomic_output(new) as tmp:
        tmp.write_text("c")
        raise RuntimeError("writer failed")
    assert new.read_text() == "b" and sorted(p.name for p in tmp_path.iterdir()) == ["new.txt"]


def test_a_number_of_thousands_of_digits_and_a_fifo_are_refused_in_one_line(tmp_path: Path) -> None:
    big = tmp_path / "big.yaml"
    big.write_text("seed: 1" + "0" * 5000 + "\n")
    with pytest.raises(ConfigError, match=r"big.yaml: invalid YAML: a value it cannot read: .*5001 digits$"):
        load_config(RunCfg, big)
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)  # reading it would block until a writer comes
    with pytest.raises(ConfigError, match="fifo.yaml: not a regular file"):
        load_config(RunCfg, fifo)

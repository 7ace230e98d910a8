import tomllib
from pathlib import Path

import pytest

from service.core.config import DEFAULT_CONFIG, Config, MappingMethod, build_config, load_config
from service.core.errors import ConfigError


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "oslim.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_default_file_equals_model_defaults() -> None:
    assert load_config() == Config()
    # every key of the model appears in the file, so the file documents them all
    data = tomllib.loads(DEFAULT_CONFIG.read_text(encoding="utf-8"))
    for section, model in Config().model_dump().items():
        assert set(data[section]) == set(model), section


def test_contract_keys_exist() -> None:
    c = Config()
    for key in ("vehicle.id", "mavlink.url", "mavlink.guided_mode", "area.x_min", "area.x_max",
                "area.y_min", "area.y_max", "area.columns", "area.rows", "area.obstacles",
                "sensor.name", "sensor.threshold", "mapping.method", "planning.method",
                "zenoh.mode", "zenoh.connect", "zenoh.listen", "recorder.dir"):  # fmt: skip
        section, name = key.split(".")
        assert hasattr(getattr(c, section), name), key


def test_unknown_key_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"area\.colums: unknown key"):
        load_config(write(tmp_path, "[area]\ncolums = 10\n"))


@pytest.mark.parametrize(
    ("section", "key"),
    [
        ("planning", "zigzag_spacing_m"),
        ("declaration", "steady_hit_rate"),
        ("planning", "flat_map_ratio"),
        ("planning", "lost_trace_mass"),
        ("planning", "cast_legs"),
        ("planning", "cast_width_m"),
        ("declaration", "persist_s"),
    ],
)
def test_a_removed_key_says_what_to_do(tmp_path: Path, section: str, key: str) -> None:
    with pytest.raises(ConfigError, match=rf"{section}\.{key}: removed: .*delete the key"):
        load_config(write(tmp_path, f"[{section}]\n{key} = 0.5\n"))


def test_unknown_section_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"mapper: unknown key"):
        load_config(write(tmp_path, "[mapper]\nmethod = 'hmm'\n"))


def test_wrong_type_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"area\.columns: .*integer.*'ten'"):
        load_config(write(tmp_path, "[area]\ncolumns = 'ten'\n"))


def test_negative_cell_count_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"area\.rows: Input should be greater than 0 \(got -3\)"):
        load_config(write(tmp_path, "[area]\nrows = -3\n"))


def test_x_min_not_below_x_max(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"area: .*x_min \(100\.0\) must be less than x_max \(0\.0\)"):
        load_config(write(tmp_path, "[area]\nx_min = 100.0\nx_max = 0.0\n"))


def test_bad_method_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"mapping\.method: .*'hmm', 'bayes' or 'pomdp'"):
        load_config(write(tmp_path, "[mapping]\nmethod = 'kalman'\n"))


def test_bad_obstacle_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"area: .*obstacles\[0\]"):
        load_config(write(tmp_path, "[area]\nobstacles = [[10.0, 10.0, 5.0, 20.0]]\n"))


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such configuration file"):
        load_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[area\n"))


def test_overrides() -> None:
    c = load_config(overrides=["area.columns=50", "mapping.method=hmm", "vehicle.id=auv-7",
                               "area.obstacles=[[1, 2, 3, 4]]", "mavlink.altitude_m=-2"])  # fmt: skip
    assert c.area.columns == 50
    assert c.mapping.method is MappingMethod.HMM
    assert c.vehicle.id == "auv-7"
    assert c.area.obstacles == [(1.0, 2.0, 3.0, 4.0)]
    assert c.mavlink.altitude_m == -2.0


@pytest.mark.parametrize("text", ["area.columns", "columns=3", ".x=1", "area.=1"])
def test_malformed_override(text: str) -> None:
    with pytest.raises(ConfigError, match=r"section\.key=value"):
        build_config({}, [text])


def test_override_validated_like_the_file() -> None:
    with pytest.raises(ConfigError, match=r"area\.columns: Input should be greater than 0"):
        build_config({}, ["area.columns=0"])
    with pytest.raises(ConfigError, match=r"zenoh\.nope: unknown key"):
        build_config({}, ["zenoh.nope=1"])

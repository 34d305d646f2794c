"""Every TOML file the gateway reads fails in one line naming the file and the fault
(gateway/tomlfile.py), whichever command reads it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from gateway.greenhouse import GreenhouseError, load_greenhouse
from gateway.model import build_model
from gateway.model.params_file import ParamsFileError, read_params
from gateway.tomlfile import read_toml

ROOT = Path(__file__).resolve().parents[1]


def _not_utf8(tmp_path: Path) -> Path:
    p = tmp_path / "latin1.toml"
    p.write_bytes(b'# first line\nname = "caf\xe9"\n')
    return p


def test_read_toml_names_the_file_and_the_fault(tmp_path: Path) -> None:
    good = tmp_path / "good.toml"
    good.write_text('[a]\nb = 1\n')
    assert read_toml(good) == {"a": {"b": 1}}
    cases = {
        tmp_path / "missing.toml": "cannot read thing: No such file or directory",
        tmp_path: "is a directory, not a thing",
        _not_utf8(tmp_path): "line 2: not UTF-8 text",
    }
    bad = tmp_path / "bad.toml"
    bad.write_text("[a\n")
    cases[bad] = "invalid TOML"
    for path, fault in cases.items():
        with pytest.raises(KeyError) as err:
            read_toml(path, KeyError, "thing")
        message = err.value.args[0]
        assert message.startswith(f"{path}: ") and fault in message, message
        assert "\n" not in message


def test_greenhouse_and_params_files_say_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(GreenhouseError, match="is a directory, not a greenhouse file"):
        load_greenhouse(tmp_path)  # was an IsADirectoryError traceback
    with pytest.raises(GreenhouseError, match="line 2: not UTF-8"):
        load_greenhouse(_not_utf8(tmp_path))  # was a UnicodeDecodeError traceback
    with pytest.raises(ParamsFileError, match="not UTF-8"):
        read_params(_not_utf8(tmp_path), build_model("prototype", load_greenhouse("biskra-prototype")))


@pytest.mark.parametrize(("command", "status"), [
    (["router", "--config"], os.EX_CONFIG), (["subscribe", "--config"], os.EX_CONFIG),
    (["run", "--config"], os.EX_CONFIG)])  # the services' config errors exit 78, not restarted
def test_a_config_that_is_not_utf8_is_one_line_and_its_exit_status(
        tmp_path: Path, command: list[str], status: int) -> None:
    r = subprocess.run([sys.executable, "-m", "gateway", *command, str(_not_utf8(tmp_path))],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == status, r.stderr
    assert r.stderr.count("\n") == 1 and "latin1.toml: line 2: not UTF-8 text" in r.stderr, r.stderr


def test_a_params_file_lacking_a_key_starts_it_at_the_greenhouses_default(tmp_path: Path) -> None:
    """Keys a params file lacks start where they would without a file: the greenhouse's cover
    transmission for c_tsw (0.7 for biskra-prototype), not the model's generic default."""
    gh = load_greenhouse("biskra-prototype")
    model = build_model("almeria", gh)
    p = tmp_path / "p.toml"
    p.write_text('model = "almeria"\n[params]\nc_asw = 0.5\n')
    theta = read_params(p, model, gh)
    assert theta[model.index("c_asw")] == 0.5
    assert theta[model.index("c_tsw")] == pytest.approx(gh.cover_transmission)
    assert gh.cover_transmission != model.defaults()[model.index("c_tsw")]  # the case matters
    others = [j for j, n in enumerate(model.names) if n != "c_asw"]
    assert list(theta[others]) == list(model.defaults(gh)[others])

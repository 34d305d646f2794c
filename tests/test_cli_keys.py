"""``python -m gateway keys``: device keys made, rotated and listed; the file never world-readable;
the printed line is what the real firmware's config.json takes."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from gateway.cli import main
from gateway.store.keys import key_id, load_keys
from tests.mcu_fakes.hostenv import MCU, micropython, run_mpy


def add(keys: Path, *args: str) -> int:
    return main(["keys", "add", *args, "--keys", str(keys)])


def printed_key(out: str) -> tuple[int, bytes]:
    lines = out.strip().splitlines()
    assert len(lines) == 1, out  # stdout is the config line alone: scripts can take it
    d = json.loads("{" + lines[0].rstrip(",") + "}")
    assert set(d) == {"device_id", "key"}
    return d["device_id"], bytes.fromhex(d["key"])


def test_add_creates_an_owner_only_file_and_prints_the_firmware_line(tmp_path: Path,
                                                                      capsys) -> None:
    keys = tmp_path / "keys.txt"
    old = os.umask(0o022)
    try:
        assert add(keys, "7") == 0
    finally:
        os.umask(old)
    cap = capsys.readouterr()
    dev, key = printed_key(cap.out)
    assert dev == 7 and len(key) == 32
    assert oct(keys.stat().st_mode & 0o777) == "0o600"
    assert load_keys(keys) == {7: key}  # the gateway accepts what it made
    assert key_id(key) in cap.err and "restart" in cap.err
    assert add(keys, "8", "--name", "north house") == 0
    _, key8 = printed_key(capsys.readouterr().out)
    assert key8 != key and load_keys(keys) == {7: key, 8: key8}
    assert keys.read_text().splitlines()[-1].endswith(" north house")


def test_existing_id_is_refused_unless_rotated(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "keys.txt"
    keys.write_text("# greenhouse north\n7 " + "ab" * 32 + " north\n\n9 " + "cd" * 32 + "\n")
    os.chmod(keys, 0o600)
    before = keys.read_text()
    assert add(keys, "7") == 2
    err = capsys.readouterr().err
    assert "device 7 already has a key" in err and f"keys rotate 7 --keys {keys}" in err, err
    assert keys.read_text() == before
    assert main(["keys", "rotate", "7", "--keys", str(keys)]) == 0
    dev, key = printed_key(capsys.readouterr().out)
    assert dev == 7 and key != bytes.fromhex("ab" * 32)
    lines = keys.read_text().splitlines()
    assert lines[0] == "# greenhouse north" and lines[1] == f"7 {key.hex()} north"
    assert lines[2:] == ["", "9 " + "cd" * 32]  # the rest untouched
    assert main(["keys", "rotate", "8", "--keys", str(keys)]) == 2
    assert "no device 8 in" in capsys.readouterr().err


def test_rotate_replaces_the_published_example_key(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "keys.txt"
    keys.write_text((Path(__file__).parents[1] / "images/gateway/keys.example.txt").read_text())
    os.chmod(keys, 0o600)
    assert main(["keys", "rotate", "7", "--keys", str(keys)]) == 0
    _, key = printed_key(capsys.readouterr().out)
    assert load_keys(keys) == {7: key}


def test_world_readable_or_odd_paths_are_refused_unchanged(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "keys.txt"
    keys.write_text("7 " + "ab" * 32 + "\n")
    os.chmod(keys, 0o644)
    assert add(keys, "8") == 2
    assert "chmod 600" in capsys.readouterr().err
    assert keys.read_text() == "7 " + "ab" * 32 + "\n" and keys.stat().st_mode & 0o777 == 0o644
    assert add(tmp_path, "8") == 2
    assert "is a directory" in capsys.readouterr().err
    assert add(tmp_path / "no" / "keys.txt", "8") == 2
    assert "no such directory" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        add(tmp_path / "k2", "4294967296")
    assert "device id" in capsys.readouterr().err


def test_list_shows_ids_never_keys(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "keys.txt"
    assert add(keys, "7", "--name", "south") == 0
    _, key = printed_key(capsys.readouterr().out)
    assert main(["keys", "list", "--keys", str(keys)]) == 0
    out = capsys.readouterr().out
    assert "7" in out and key_id(key) in out and "south" in out and key.hex() not in out


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
def test_printed_line_is_what_the_firmware_config_takes(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "keys.txt"
    assert add(keys, "4242") == 0
    line = capsys.readouterr().out.strip()
    # The line replaces the device_id and key lines of the shipped example config.
    example = (MCU / "config.example.json").read_text().splitlines()
    assert example[1].strip().startswith('"device_id"') and example[2].strip().startswith('"key"')
    board = tmp_path / "board"
    board.mkdir()
    (board / "config.json").write_text("\n".join([example[0], "  " + line, *example[3:]]))
    (board / "show.py").write_text(
        "import config, binascii\nc = config.load('config.json')\n"
        "print(c.device_id, binascii.hexlify(c.key).decode())\n")
    r = run_mpy(board / "show.py", cwd=board, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    dev, hexkey = r.stdout.split()
    assert load_keys(keys) == {int(dev): bytes.fromhex(hexkey)}


def test_a_keys_file_that_does_not_exist_is_said_so(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "kyes.txt"  # a typo of the file's name
    assert main(["keys", "rotate", "7", "--keys", str(keys)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: {keys}: no such keys file, so no device 7 to rotate; add it with: "
                   f"python -m gateway keys add 7 --keys {keys}")
    assert main(["keys", "list", "--keys", str(keys)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: {keys}: no such keys file; make it with: python -m gateway keys add "
                   f"DEVICE_ID --keys {keys}")
    assert not keys.exists()


def test_a_key_length_that_is_not_a_number_is_said_in_words(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        add(tmp_path / "keys.txt", "7", "--bytes", "thirty-two")
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1].endswith("argument --bytes: key length 'thirty-two' is not a "
                                         "whole number of bytes (16 to 64; 32 recommended)")
    assert "_key_bytes" not in err and not (tmp_path / "keys.txt").exists()

"""A new user's mistakes with the gateway's service commands (status, run, ingest, keys,
subscribe) and the help: each is one line naming the file, key or option and what was wrong,
exit status 2 (78, EX_CONFIG, for a wrong config of run or keys file of ingest: the systemd
units do not restart on it), never a traceback; every numeric option's help shows its default."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import pytest

from gateway.cli import main
from tests.cli_mistakes_common import help_pages, lines_too_wide_or_broken, one_error_line


@pytest.mark.parametrize("text,message", [
    ('name = "north"\n[geometry]\nvolume = 3\n', "gateway: missing (required): a [gateway] table"),
    ('[gateway]\nfarm = "f"\n', "gateway.db: missing (required)"),
    ('[gateway]\ndb = 5\n', "gateway.db: must be a path in quotes, got 5"),
    ('[gateway\ndb = "x.db"\n', "invalid TOML"),
])
def test_status_names_what_is_wrong_in_the_config(capsys, tmp_path, text, message):
    config = tmp_path / "gateway.toml"
    config.write_text(text)
    assert main(["status", "--once", "--config", str(config)]) == 2
    assert f"{config}: {message}" in one_error_line(capsys)


def test_status_on_a_config_whose_store_is_not_made_yet_says_so(capsys, tmp_path):
    config = tmp_path / "gateway.toml"
    config.write_text('[gateway]\ndb = "serra.db"\n')
    assert main(["status", "--once", "--config", str(config)]) == 2
    line = one_error_line(capsys)
    assert f"{tmp_path / 'serra.db'}: no such store (the gateway.db of {config}" in line


@pytest.mark.parametrize("db,message", [
    ("no-such-folder/serra.db", "does not exist (the gateway creates the store serra.db, not its"),
    (".", "is a folder; name the store's file"),
])
def test_run_check_refuses_a_store_it_could_not_create(capsys, tmp_path, db, message):
    config = _checked_config(capsys, tmp_path, "", db=db)
    line = one_error_line(capsys)
    assert f"{config}: gateway.db: " in line and message in line


@pytest.mark.parametrize("option,value,message", [
    ("--retention-days", "-3", "must be at least 1, got '-3'"),  # would delete every sample
    ("--retention-days", "nan", "must be at least 1, got 'nan'"),
    ("--max-db-mb", "0", "must be at least 1, got '0'"),
    ("--batch-delay", "-1", "must be at least 0, got '-1'"),
    ("--baudrate", "9600.5", "expected a whole number, got '9600.5'"),
    ("--listen", "127.0.0.1:568300", "port 568300 of '127.0.0.1:568300' is outside 0..65535"),
])
def test_ingest_refuses_numbers_outside_the_configs_bounds(capsys, tmp_path, option, value,
                                                           message):
    with pytest.raises(SystemExit) as exc:  # argparse's usage error, before anything starts
        main(["ingest", "--db", str(tmp_path / "s.db"), "--keys", str(tmp_path / "k.txt"),
              option, value])
    assert exc.value.code == 2
    assert f"argument {option}: {message}" in capsys.readouterr().err
    assert not (tmp_path / "s.db").exists()


def test_ingest_without_its_keys_file_names_it_and_how_to_make_it(capsys, tmp_path):
    keys = tmp_path / "keys.txt"
    assert main(["ingest", "--db", str(tmp_path / "s.db"), "--keys", str(keys)]) == os.EX_CONFIG
    line = one_error_line(capsys)
    assert f"{keys}: cannot read the keys file: No such file" in line
    assert "python -m gateway keys add" in line and "Errno" not in line


def test_keys_help_says_what_add_says_about_restarting(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["keys", "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "restart it afterwards" not in text and "no restart" in text
    assert main(["keys", "add", "7", "--keys", str(tmp_path / "keys.txt")]) == 0
    assert "no restart" in capsys.readouterr().err  # what add says agrees with the help


def test_subscribe_refuses_a_duration_that_is_not_positive(capsys, tmp_path):
    assert main(["subscribe", "--connect", "tcp/127.0.0.1:1", "--db", str(tmp_path / "c.db"),
                 "--duration", "-5"]) == 2
    assert "--duration -5: must be a positive number of seconds" in one_error_line(capsys)
    assert not (tmp_path / "c.db").exists()


def test_status_connect_without_a_protocol_is_said_in_words(capsys):
    assert main(["status", "--once", "--connect", "192.168.1.20:7447"]) == 2
    line = one_error_line(capsys)
    assert "--connect '192.168.1.20:7447': expected PROTOCOL/ADDRESS" in line
    assert "Json5Err" not in line


def _numeric_options_without_default(parser: argparse.ArgumentParser, prefix: str = ""):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _numeric_options_without_default(sub, f"{prefix}{name} ")
        elif (action.option_strings and action.type not in (None, str)
              and action.default not in (None, argparse.SUPPRESS, False)
              and action.help != argparse.SUPPRESS):
            d, text = action.default, action.help or ""
            shown = ["%(default)", f"({d})", f"default {d}", f"default: {d}"]
            if isinstance(d, int | float):
                shown += [f"({d:g})", f"default {d:g}", f"default: {d:g}"]
            if not any(s in text for s in shown):
                yield f"{prefix}{action.option_strings[0]}"


def test_every_numeric_option_with_a_default_shows_it_in_help():
    from gateway.cli import build_parser
    from gateway.ingest.service import build_parser as ingest_parser
    from training.appliance.cli import add_parser as run_parser
    from training.simulate.cli import add_parser as simulate_parser
    from training.vsensor.cli import build_parser as vsensor_parser

    training = argparse.ArgumentParser()
    sub = training.add_subparsers()
    simulate_parser(sub)
    run_parser(sub)
    parsers = [build_parser(), ingest_parser(), vsensor_parser(), training]
    assert [o for p in parsers for o in _numeric_options_without_default(p)] == []


def test_every_gateway_help_page_fits_80_columns_unbroken(monkeypatch):
    """At 80 columns the command list broke 'PCA-NARX' at its hyphen (and replay's example
    'almeria-palmerillas'); subscribe's, certs' and router's raw texts ran to 96 columns and
    status's usage to 92 (argparse never splits a group of exclusive options)."""
    from gateway.cli import build_parser
    from gateway.ingest.service import build_parser as ingest_parser

    monkeypatch.setenv("COLUMNS", "80")  # what argparse wraps to
    pages = {**help_pages(build_parser()), **help_pages(ingest_parser())}
    assert len(pages) == 1 + 12 + 3 + 1  # the tool, its commands, keys' actions, ingest's service
    assert lines_too_wide_or_broken(pages) == []
    assert "(PCA-NARX, ONNX)" in pages["python -m gateway"]


def test_subscribe_says_its_counters_in_words(capsys, tmp_path):
    assert main(["subscribe", "--connect", "tcp/127.0.0.1:1", "--db", str(tmp_path / "c.db"),
                 "--duration", "0.3"]) == 0
    err = capsys.readouterr().err
    assert "subscribe stopped: received 0, stored 0, repeats 0" in err
    assert "SubscribeStats(" not in err


def test_a_rejected_packet_is_logged_with_its_sender_as_host_port(caplog, tmp_path):
    import logging

    from gateway.ingest.core import IngestCore, peer_text
    from gateway.store import Store

    core = IngestCore(Store(tmp_path / "g.db"), {7: b"\x00" * 32})
    with caplog.at_level(logging.WARNING, logger="serra.ingest"):
        core.handle(b"hello", ("192.168.4.7", 40000), lambda data, peer: None)
    assert "packet from 192.168.4.7:40000 rejected: short 5 bytes" in caplog.text
    assert peer_text(("fe80::1", 5683, 0, 0)) == "[fe80::1]:5683"
    assert peer_text("/dev/ttyUSB0") == "/dev/ttyUSB0"
    core.store.close()


def test_bench_runner_lists_its_benches_and_refuses_an_unknown_one():
    import subprocess
    import sys

    run = Path(__file__).parent / "bench" / "run.py"
    r = subprocess.run([sys.executable, str(run), "--help"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0 and "calibration" in r.stdout and "failed" not in r.stderr
    r = subprocess.run([sys.executable, str(run), "calibratoin"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "no bench named calibratoin (benches: " in r.stderr
    assert "== bench" not in r.stdout  # nothing was started


def test_verbose_is_taken_after_the_command_too(capsys, tmp_path):
    """'calibrate ... -v' was 'unrecognized arguments: -v' (only 'python -m gateway -v
    calibrate ...' worked), and '-v ingest ...' did not reach the ingest service's parser."""
    from gateway.cli import build_parser

    parser = build_parser()
    base = ["calibrate", "--data", "k.csv", "--greenhouse", "biskra-prototype", "--model",
            "prototype"]
    assert parser.parse_args([*base, "-v"]).verbose and parser.parse_args(["-v", *base]).verbose
    assert not parser.parse_args(base).verbose
    assert parser.parse_args(["keys", "list", "--keys", "k.txt", "--verbose"]).verbose
    keys = tmp_path / "keys.txt"
    assert main(["keys", "add", "7", "--keys", str(keys), "-v"]) == 0
    assert '"device_id": 7' in capsys.readouterr().out
    missing = tmp_path / "none.txt"  # refused before the service listens
    assert main(["-v", "ingest", "--db", str(tmp_path / "s.db"), "--keys", str(missing)]) == os.EX_CONFIG
    assert f"{missing}: cannot read the keys file" in one_error_line(capsys)



@pytest.mark.parametrize("before,after", [(["-q"], []), ([], ["-q"]), (["-q", "-v"], []),
                                          (["--verbose"], ["--quiet"]), (["-vq"], [])])
def test_quiet_is_taken_before_or_after_every_command(capsys, tmp_path, before, after):
    """'-q ingest ...' was "unrecognized arguments: --db ... --keys ..." (only -v before ingest
    reached the service's parser), 'ingest ... -q' "unrecognized arguments: -q"."""
    from gateway.cli import build_parser

    parser = build_parser()
    base = ["calibrate", "--data", "k.csv", "--greenhouse", "biskra-prototype", "--model",
            "prototype"]
    args = parser.parse_args([*before, *base, *after])
    assert args.quiet and args.verbose == any(a in before for a in ("-v", "--verbose", "-vq"))
    assert parser.parse_args([*before, "keys", "list", "--keys", "k.txt", *after]).quiet
    missing = tmp_path / "none.txt"  # refused before the service listens: the service's line
    ingest = ["ingest", "--db", str(tmp_path / "s.db"), "--keys", str(missing)]
    assert main([*before, *ingest, *after]) == os.EX_CONFIG
    assert f"{missing}: cannot read the keys file" in one_error_line(capsys)


def _defaults_not_called_default(parser: argparse.ArgumentParser, prefix: str = ""):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _defaults_not_called_default(sub, f"{prefix}{name} ")
        elif (action.option_strings and action.default not in (None, argparse.SUPPRESS, False, [])
              and "default" not in (action.help or "")):
            yield f"{prefix}{action.option_strings[0]}"


def test_every_gateway_option_with_a_default_says_default_in_one_wording():
    """'(rsba)', '(0.5)', '(825)' beside '(default 60)', '(default 0)': one wording, so a
    reader of two commands' help never wonders whether '(2)' is a default or an example."""
    from gateway.cli import build_parser

    assert list(_defaults_not_called_default(build_parser())) == []


def test_every_help_page_fits_a_terminal(monkeypatch):
    """The subscribe description came out as one 400-character line (its raw formatter, kept
    for the epilog's examples, does not wrap), and the four model names made the data commands'
    usage and option lines overrun; no line of any page is now over 100 characters at 80."""
    from gateway.cli import build_parser

    monkeypatch.setenv("COLUMNS", "80")  # what argparse wraps to

    def pages(parser: argparse.ArgumentParser, name: str):
        yield name, parser.format_help()
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub, child in action.choices.items():
                    yield from pages(child, f"{name} {sub}")

    long = [(name, line) for name, text in pages(build_parser(), "gateway")
            for line in text.splitlines() if len(line) > 100]
    assert long == []


@pytest.mark.parametrize(("args", "message"), [
    (["--dsn", "dbname=x"], "give db (SQLite) or dsn (PostgreSQL), not both (--db or --dsn)"),
    (["--mode", "client"], "client mode needs a router in connect (--connect ENDPOINT)"),
])
def test_subscribe_conflicts_on_the_command_line_name_its_options(capsys, tmp_path, args,
                                                                  message):
    assert main(["subscribe", "--db", str(tmp_path / "c.db"), *args]) == 78  # EX_CONFIG
    assert one_error_line(capsys) == f"error: command line: {message}"
    assert list(tmp_path.iterdir()) == []  # no store made


@pytest.mark.parametrize(("in_gateway", "tables", "said"), [
    ("status_every_s = 0\n", "", "gateway.status_every_s: 0 is below its minimum 1"),
    ("", "[outbox]\nalarm_fraction = 1.5\n", "outbox.alarm_fraction: 1.5 is outside 0.05..1"),
])
def test_run_check_says_a_number_out_of_range_without_inf(capsys, tmp_path, in_gateway, tables,
                                                          said):
    """'0.0 is outside 1.0..inf' for a whole number of seconds: the bound is now said as one."""
    config = _checked_config(capsys, tmp_path, in_gateway + tables)
    assert one_error_line(capsys) == f"error: {config}: {said}"


@pytest.mark.parametrize(("listen", "said"), [
    ("0.0.0.0:70000", "port 70000 of '0.0.0.0:70000' is outside 0..65535"),
    ("gateway-pi:5683", "'gateway-pi' is not an IP address: give the address to listen on"),
])
def test_run_check_reads_ingest_listen_as_ingest_listen_does(capsys, tmp_path, listen, said):
    """The config's [ingest] listen had a reader of its own: a port out of range was 'expected
    HOST:PORT', and a host name passed --check (ingest --listen refuses it: never resolved)."""
    config = _checked_config(capsys, tmp_path, f'[ingest]\nlisten = "{listen}"\n')
    assert one_error_line(capsys).startswith(f"error: {config}: ingest.listen: {said}")


def _checked_config(capsys, tmp_path, more: str, db: str = "serra.db"):
    """A gateway.toml of one greenhouse (store ``db``) with ``more`` after its [gateway] keys,
    refused by ``run --check`` (exit 78, EX_CONFIG); its path."""
    assert main(["keys", "add", "7", "--keys", str(tmp_path / "keys.txt")]) == 0
    config = tmp_path / "gateway.toml"
    config.write_text(f'[gateway]\nfarm = "f1"\ndb = "{db}"\nkeys = "keys.txt"\n{more}'
                      '[[greenhouse]]\nname = "north"\ngreenhouse = "biskra-prototype"\n'
                      'model = "prototype"\ninside = 7\n')
    capsys.readouterr()
    assert main(["run", "--config", str(config), "--check"]) == os.EX_CONFIG
    return config


@pytest.mark.parametrize(("content", "said"), [
    ("time,t_in\n", "not an SQLite database, not a Serra store"),
    (None, "not a Serra store (schema version 0; missing tables devices, meta, minute, samples) "
           "(a cloud store"),
])
def test_run_check_refuses_a_gateway_db_that_is_another_file(capsys, tmp_path, content, said):
    """--check said 'ok' of a gateway.db naming a CSV or the cloud store's file; only the start
    refused it (or, for the cloud store, a gateway store would have been made inside it)."""
    from gateway.cloud.store import open_store

    assert main(["keys", "add", "7", "--keys", str(tmp_path / "keys.txt")]) == 0
    db = tmp_path / "other.db"
    if content is None:
        open_store(db, None, "serra").close()
    else:
        db.write_text(content)
    before = db.read_bytes()
    config = tmp_path / "gateway.toml"
    config.write_text('[gateway]\nfarm = "f1"\ndb = "other.db"\nkeys = "keys.txt"\n[[greenhouse]]\n'
                      'name = "north"\ngreenhouse = "biskra-prototype"\nmodel = "prototype"\n'
                      'inside = 7\n')
    capsys.readouterr()
    assert main(["run", "--config", str(config), "--check"]) == os.EX_CONFIG
    assert one_error_line(capsys).startswith(f"error: {config}: gateway.db: {db}: {said}")
    assert db.read_bytes() == before


def test_version_is_printed_for_a_bug_report(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"python -m gateway {version('serra')}"

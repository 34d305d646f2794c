"""The fleet PKI: CA, router/gateway/client certificates, key modes, the key-file check."""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID

from gateway.net.certs import (
    CertError,
    check_key_file,
    common_name,
    issue,
    load_ca,
    load_certificate,
    load_private_key,
    make_ca,
)

ROOT = Path(__file__).resolve().parents[2]


def _mode(p: Path) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


def test_certificates_chain_to_the_ca_with_roles_and_names(tmp_path: Path) -> None:
    old = os.umask(0)  # a permissive umask must not leak into the key modes
    try:
        ca = make_ca(tmp_path)
        router = issue(ca, "router", "cloud", tmp_path, hosts=["127.0.0.1", "localhost", "cloud.example.org"])
        gateway = issue(ca, "gateway", "farm-a", tmp_path)
    finally:
        os.umask(old)
    ca_cert = load_certificate(ca.cert)
    for issued in (router, gateway):
        cert = load_certificate(issued.cert)
        cert.verify_directly_issued_by(ca_cert)
        assert _mode(issued.key) == 0o600
        assert common_name(cert) == issued.name
    assert _mode(ca.key) == 0o600
    r = load_certificate(router.cert)
    san = r.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.IPAddress) == [ipaddress.ip_address("127.0.0.1")]
    assert san.get_values_for_type(x509.DNSName) == ["localhost", "cloud.example.org"]
    eku = r.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert set(eku) == {ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH}
    g = load_certificate(gateway.cert)
    assert list(g.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value) == [
        ExtendedKeyUsageOID.CLIENT_AUTH]
    assert g.not_valid_after_utc - g.not_valid_before_utc == dt.timedelta(days=825)
    assert load_ca(tmp_path).name == "serra-fleet-ca"


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o620])
def test_a_key_readable_or_writable_by_others_is_refused(tmp_path: Path, mode: int) -> None:
    ca = make_ca(tmp_path)
    g = issue(ca, "gateway", "farm-a", tmp_path)
    assert check_key_file(g.key) == g.key
    os.chmod(g.key, mode)
    with pytest.raises(CertError) as err:
        load_private_key(g.key)
    message = str(err.value)
    assert "\n" not in message and str(g.key) in message and f"{mode:04o}" in message
    assert f"chmod 600 {g.key}" in message


def test_names_files_and_overwrites(tmp_path: Path) -> None:
    ca = make_ca(tmp_path)
    with pytest.raises(CertError, match="farm/a"):
        issue(ca, "gateway", "farm/a", tmp_path)  # would be two key-expression chunks
    with pytest.raises(CertError, match="role 'admin'"):
        issue(ca, "admin", "x", tmp_path)
    first = issue(ca, "gateway", "farm-a", tmp_path)
    before = first.cert.read_bytes()
    with pytest.raises(CertError, match="exists"):
        issue(ca, "gateway", "farm-a", tmp_path)
    assert first.cert.read_bytes() == before
    issue(ca, "gateway", "farm-a", tmp_path, overwrite=True)
    assert first.cert.read_bytes() != before
    with pytest.raises(CertError, match="cannot read private key"):
        check_key_file(tmp_path / "missing.key")
    (tmp_path / "junk.pem").write_text("not a certificate")
    with pytest.raises(CertError, match="junk.pem: not a PEM certificate"):
        load_certificate(tmp_path / "junk.pem")


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gateway", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_certs_command_makes_a_ca_then_reuses_it(tmp_path: Path) -> None:
    out = tmp_path / "certs"
    r = _cli("certs", "--out", str(out), "--router", "cloud=cloud.example.org,192.0.2.7",
             "--gateway", "farm-a", "--client", "store")
    assert r.returncode == 0, r.stderr
    assert _mode(out) == 0o700
    names = sorted(p.name for p in out.iterdir())
    assert names == ["ca.key", "ca.pem", "client-store.key", "client-store.pem", "gateway-farm-a.key",
                     "gateway-farm-a.pem", "router-cloud.key", "router-cloud.pem"]
    assert all(_mode(out / n) == 0o600 for n in names if n.endswith(".key"))
    san = load_certificate(out / "router-cloud.pem").extensions.get_extension_for_class(
        x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.IPAddress) == [ipaddress.ip_address("127.0.0.1"),
                                                       ipaddress.ip_address("192.0.2.7")]
    ca_before = (out / "ca.pem").read_bytes()
    r = _cli("certs", "--out", str(out), "--gateway", "farm-b")
    assert r.returncode == 0, r.stderr
    assert (out / "ca.pem").read_bytes() == ca_before
    load_certificate(out / "gateway-farm-b.pem").verify_directly_issued_by(load_certificate(out / "ca.pem"))
    r = _cli("certs", "--out", str(out), "--gateway", "farm-b")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "exists" in r.stderr
    os.chmod(out / "ca.key", 0o644)
    r = _cli("certs", "--out", str(out), "--gateway", "farm-c")
    assert r.returncode == 2 and "ca.key: private key mode is 0644" in r.stderr


def test_a_request_made_on_the_device_is_signed_without_its_key(tmp_path: Path) -> None:
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    device_key = ec.generate_private_key(ec.SECP256R1())  # made and kept on the gateway
    csr = (x509.CertificateSigningRequestBuilder()
           .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "farm-d")]))
           .sign(device_key, hashes.SHA256()))
    request = tmp_path / "farm-d.csr"
    request.write_bytes(csr.public_bytes(serialization.Encoding.PEM))
    out = tmp_path / "certs"
    r = _cli("certs", "--out", str(out), "--sign", f"gateway:{request}")
    assert r.returncode == 0, r.stderr
    assert "key stays on the device" in r.stdout
    cert = load_certificate(out / "gateway-farm-d.pem")
    cert.verify_directly_issued_by(load_certificate(out / "ca.pem"))
    assert common_name(cert) == "farm-d" and cert.public_key() == device_key.public_key()
    assert not (out / "gateway-farm-d.key").exists()
    r = _cli("certs", "--out", str(out), "--sign", f"admin:{request}")
    assert r.returncode == 2 and "expected ROLE:FILE.csr" in r.stderr
    request.write_text("junk")
    r = _cli("certs", "--out", str(out), "--sign", f"gateway:{request}")
    assert r.returncode == 2 and "not a PEM certificate request" in r.stderr

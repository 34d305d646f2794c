"""A small X.509 PKI for the Zenoh fleet: one CA, router, gateway and client certificates.

Every certificate is EC P-256 / SHA-256 signed by the fleet CA. The common name (CN) is the
identity the routers' access control matches (``cert_common_names``): a gateway's CN is its
farm, a subscriber's CN is its name, a router's CN is its name. Private keys are PKCS#8 PEM,
unencrypted (Zenoh reads them itself), written with mode 0600; `check_key_file` refuses a key
that the group or other users can read or write, before any path is handed to Zenoh.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

# A name becomes a key-expression chunk (serra/<farm>/...) and a file name: keep it plain.
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,62}$")
ROLES = ("ca", "router", "gateway", "client")


class CertError(ValueError):
    """A certificate or key problem, as one line naming the file."""


@dataclass(frozen=True)
class Issued:
    """One certificate and its private key on disk."""

    name: str  # the common name
    role: str  # one of ROLES
    cert: Path
    key: Path | None  # None: the key stayed on the device (sign_csr)


def check_name(name: str, what: str = "name") -> str:
    if not NAME_RE.match(name):
        raise CertError(
            f"{what} {name!r}: use 1-63 letters, digits, '.', '_' or '-', starting with a letter "
            f"or digit (it becomes a Zenoh key-expression chunk and a file name)")
    return name


def check_key_file(path: str | Path) -> Path:
    """The key file, if it exists and only its owner may read or write it; else CertError."""
    path = Path(path)
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except OSError as exc:
        raise CertError(f"{path}: cannot read private key: {exc.strerror}") from None
    if mode & 0o077:
        raise CertError(
            f"{path}: private key mode is {mode:04o}, readable or writable by group or others; "
            f"refusing it (run: chmod 600 {path})")
    return path


def load_private_key(path: str | Path) -> ec.EllipticCurvePrivateKey:
    path = check_key_file(path)
    try:
        key = serialization.load_pem_private_key(path.read_bytes(), password=None)
    except (ValueError, TypeError) as exc:
        raise CertError(f"{path}: not an unencrypted PEM private key ({exc})") from None
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        raise CertError(f"{path}: expected an EC private key, got {type(key).__name__}")
    return key


def load_certificate(path: str | Path) -> x509.Certificate:
    path = Path(path)
    try:
        return x509.load_pem_x509_certificate(path.read_bytes())
    except OSError as exc:
        raise CertError(f"{path}: cannot read certificate: {exc.strerror}") from None
    except ValueError as exc:
        raise CertError(f"{path}: not a PEM certificate ({exc})") from None


def common_name(cert: x509.Certificate) -> str:
    attrs = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(attrs[0].value) if attrs else ""


def _write(path: Path, data: bytes, mode: int, overwrite: bool) -> None:
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if overwrite else os.O_EXCL)
    try:
        fd = os.open(path, flags, mode)
    except FileExistsError:
        raise CertError(f"{path}: exists; not overwriting it (use --force to replace)") from None
    os.fchmod(fd, mode)  # O_CREAT's mode is masked by umask, and an existing file keeps its own
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _save(issued: Issued, cert: x509.Certificate, key: ec.EllipticCurvePrivateKey,
          overwrite: bool) -> Issued:
    assert issued.key is not None
    if not overwrite:
        for path in (issued.cert, issued.key):
            if path.exists():
                raise CertError(f"{path}: exists; not overwriting it (use --force to replace)")
    pem_key = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                serialization.NoEncryption())
    _write(issued.key, pem_key, 0o600, overwrite)
    _write(issued.cert, cert.public_bytes(serialization.Encoding.PEM), 0o644, overwrite)
    return issued


def _validity(days: float, not_before: dt.datetime | None) -> tuple[dt.datetime, dt.datetime]:
    start = not_before or dt.datetime.now(dt.UTC) - dt.timedelta(minutes=5)  # clock skew
    return start, start + dt.timedelta(days=days)


def make_ca(directory: str | Path, name: str = "serra-fleet-ca", days: float = 3650,
            overwrite: bool = False) -> Issued:
    """A self-signed CA (ca.pem, ca.key) in `directory`, created if needed."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    start, end = _validity(days, None)
    cert = (
        x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
        .public_key(key.public_key()).serial_number(x509.random_serial_number())
        .not_valid_before(start).not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False),
                       critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    issued = Issued(name, "ca", directory / "ca.pem", directory / "ca.key")
    return _save(issued, cert, key, overwrite)


def _san(hosts: list[str]) -> x509.SubjectAlternativeName:
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return x509.SubjectAlternativeName(names)


def _sign(ca: Issued, role: str, name: str, public_key: ec.EllipticCurvePublicKey,
          hosts: list[str] | None, days: float, not_before: dt.datetime | None) -> x509.Certificate:
    if role not in ROLES[1:]:
        raise CertError(f"role {role!r}: expected one of {', '.join(ROLES[1:])}")
    check_name(name, f"{role} name")
    if ca.key is None:
        raise CertError(f"{ca.cert}: the CA's private key is needed to sign")
    ca_key = load_private_key(ca.key)
    ca_cert = load_certificate(ca.cert)
    start, end = _validity(days, not_before)
    usages = [ExtendedKeyUsageOID.CLIENT_AUTH]
    if role == "router":
        usages.insert(0, ExtendedKeyUsageOID.SERVER_AUTH)
    builder = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
        .issuer_name(ca_cert.subject).public_key(public_key)
        .serial_number(x509.random_serial_number()).not_valid_before(start).not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.KeyUsage(True, False, False, False, False, False, False, False, False),
                       critical=True)
        .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                       critical=False)
    )
    if role == "router":
        builder = builder.add_extension(_san(hosts or ["127.0.0.1", "localhost"]), critical=False)
    elif hosts:
        builder = builder.add_extension(_san(hosts), critical=False)
    return builder.sign(ca_key, hashes.SHA256())


def issue(ca: Issued, role: str, name: str, directory: str | Path, *, hosts: list[str] | None = None,
          days: float = 825, not_before: dt.datetime | None = None, file_stem: str | None = None,
          overwrite: bool = False) -> Issued:
    """A new key and a certificate for `name` (its CN) signed by `ca`, as
    <directory>/<role>-<name>.pem and .key.

    Routers get serverAuth and clientAuth (they accept links and open links upstream) and a
    SAN with `hosts` (127.0.0.1 and localhost by default); gateways and clients get clientAuth.
    `not_before` and `days` exist for tests (an expired certificate).
    """
    key = ec.generate_private_key(ec.SECP256R1())
    cert = _sign(ca, role, name, key.public_key(), hosts, days, not_before)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    stem = file_stem or f"{role}-{name}"
    issued = Issued(name, role, directory / f"{stem}.pem", directory / f"{stem}.key")
    return _save(issued, cert, key, overwrite)


def sign_csr(ca: Issued, role: str, csr_path: str | Path, directory: str | Path, *,
             hosts: list[str] | None = None, days: float = 825, overwrite: bool = False) -> Issued:
    """A certificate for a request made on the device itself (its private key never leaves it).

    Only the request's public key, CN and (for a router) SAN names are used; the roles'
    usages are ours. Written as <directory>/<role>-<CN>.pem."""
    csr_path = Path(csr_path)
    try:
        csr = x509.load_pem_x509_csr(csr_path.read_bytes())
    except OSError as exc:
        raise CertError(f"{csr_path}: cannot read request: {exc.strerror}") from None
    except ValueError as exc:
        raise CertError(f"{csr_path}: not a PEM certificate request ({exc})") from None
    if not csr.is_signature_valid:
        raise CertError(f"{csr_path}: the request's signature does not match its key")
    public_key = csr.public_key()
    if not isinstance(public_key, ec.EllipticCurvePublicKey):
        raise CertError(f"{csr_path}: expected an EC (P-256) key, got {type(public_key).__name__}")
    attrs = csr.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    if not attrs:
        raise CertError(f"{csr_path}: the request has no common name (CN)")
    name = str(attrs[0].value)
    hosts = list(hosts or [])
    try:  # a router's request may name the hosts its clients dial
        san = csr.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        hosts += [str(v) for v in san.get_values_for_type(x509.IPAddress) + san.get_values_for_type(
            x509.DNSName) if str(v) not in hosts]
    except x509.ExtensionNotFound:
        pass
    try:
        cert = _sign(ca, role, name, public_key, hosts or None, days, None)
    except CertError as exc:
        raise CertError(f"{csr_path}: {exc}") from None
    path = Path(directory) / f"{role}-{name}.pem"
    if path.exists() and not overwrite:
        raise CertError(f"{path}: exists; not overwriting it (use --force to replace)")
    _write(path, cert.public_bytes(serialization.Encoding.PEM), 0o644, True)
    return Issued(name, role, path, None)


def load_ca(directory: str | Path) -> Issued:
    """The CA made by `make_ca` in `directory` (its key checked for permissions)."""
    directory = Path(directory)
    cert = load_certificate(directory / "ca.pem")
    check_key_file(directory / "ca.key")
    return Issued(common_name(cert), "ca", directory / "ca.pem", directory / "ca.key")

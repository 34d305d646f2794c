"""``python -m gateway certs``: the fleet's CA and its router, gateway and client certificates."""

from __future__ import annotations

import argparse
import ipaddress
import re
from pathlib import Path

from gateway.cli import CliError
from gateway.cli.helpformat import ExamplesHelpFormatter

DESCRIPTION = "Make the fleet's CA and its router, gateway and client certificates (EC P-256)."
EPILOG = """\
examples:
  python -m gateway certs --out certs --router cloud=cloud.example.org \\
      --router region-1=10.0.0.5 --gateway farm-a --gateway farm-b \\
      --client cloud-store
  # later, the same CA signs farm-c:
  python -m gateway certs --out certs --gateway farm-c
  # a request made on the device:
  python -m gateway certs --out certs --sign gateway:farm-d.csr

The CA (ca.pem, ca.key) is made on the first run and reused after. A gateway's certificate has
its farm as common name: the routers' access control lets it speak only under serra/<farm>/**.
Private keys are written with mode 0600. Keep ca.key off the network; copy to each machine
only ca.pem and that machine's own .pem and .key (docs/fleet.md).
"""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("certs", help="make the fleet CA and router/gateway/client certificates",
                       description=DESCRIPTION, epilog=EPILOG,
                       formatter_class=ExamplesHelpFormatter)
    p.add_argument("--out", required=True, metavar="DIR", help="folder for ca.pem and the certificates")
    p.add_argument("--router", action="append", default=[], metavar="NAME[=HOST,...]",
                   help="a router certificate; its SAN holds 127.0.0.1, localhost and the HOSTs "
                   "(names or IP addresses the clients connect to)")
    p.add_argument("--gateway", action="append", default=[], metavar="FARM",
                   help="a gateway certificate whose common name is the farm")
    p.add_argument("--client", action="append", default=[], metavar="NAME",
                   help="a subscriber or client certificate (cloud store, dashboard)")
    p.add_argument("--sign", action="append", default=[], metavar="ROLE:REQUEST.csr",
                   help="sign a request made on the device (its key never leaves it); ROLE is "
                   "gateway, client or router; the CN comes from the request")
    p.add_argument("--days", type=float, default=825, metavar="N",
                   help="validity of the certificates made now [days] (default 825)")
    p.add_argument("--ca-name", default="serra-fleet-ca", metavar="CN",
                   help="common name of a new CA (default serra-fleet-ca)")
    p.add_argument("--force", action="store_true",
                   help="replace certificates that exist (never the CA: remove it by hand)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gateway.cli.common import no_stdout
    from gateway.net.certs import CertError, check_name, issue, load_ca, make_ca, sign_csr

    no_stdout(args.out, "--out", "folder")
    out = Path(args.out)
    if not (args.router or args.gateway or args.client or args.sign) and (out / "ca.pem").exists():
        raise CliError("nothing to do: name at least one --router, --gateway, --client or --sign")
    if args.days <= 0:
        raise CliError(f"--days must be positive, got {args.days:g}")
    if out.exists() and not out.is_dir():
        raise CliError(f"--out {out}: exists and is not a folder")
    for spec in args.sign:  # every mistake before the CA is made: a typo leaves nothing behind
        role, sep, _ = spec.partition(":")
        if not sep or role not in ("gateway", "client", "router"):
            raise CliError(f"--sign {spec!r}: expected ROLE:FILE.csr, ROLE one of gateway, "
                           "client, router")
    for spec in args.router:
        for host in spec.partition("=")[2].split(","):
            _check_host(spec, host.strip())
    try:
        for option, names in (("router", [r.partition("=")[0] for r in args.router]),
                              ("gateway", args.gateway), ("client", args.client)):
            for name in names:
                check_name(name, f"{option} name")
        if not out.exists():
            out.mkdir(parents=True, mode=0o700)
        if (out / "ca.pem").exists():
            ca = load_ca(out)
            print(f"using CA {out / 'ca.pem'} ({ca.name})")
        else:
            ca = make_ca(out, args.ca_name)
            print(f"made CA  {ca.cert}  key {ca.key} (0600; keep it offline)")
        made = []
        for spec in args.router:
            name, _, hosts = spec.partition("=")
            extra = [h.strip() for h in hosts.split(",") if h.strip()]
            sans = ["127.0.0.1", "localhost"] + [h for h in extra if h not in ("127.0.0.1", "localhost")]
            made.append(issue(ca, "router", name, out, hosts=sans, days=args.days, overwrite=args.force))
        for farm in args.gateway:
            made.append(issue(ca, "gateway", farm, out, days=args.days, overwrite=args.force))
        for name in args.client:
            made.append(issue(ca, "client", name, out, days=args.days, overwrite=args.force))
        for spec in args.sign:
            role, _, csr = spec.partition(":")
            made.append(sign_csr(ca, role, csr, out, hosts=["127.0.0.1", "localhost"],
                                 days=args.days, overwrite=args.force))
    except CertError as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise CliError(f"--out {out}: {exc.strerror or exc}") from None
    for m in made:
        key = f"  key {m.key} (0600)" if m.key is not None else "  (key stays on the device)"
        print(f"{m.role:8} CN={m.name:20} {m.cert}{key}")
    return 0


_LABEL = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?")


def _check_host(spec: str, host: str) -> None:
    """A router's SAN entry: an IP address or a DNS name, as the clients' endpoints name the
    router. '10.0.0.5:7447' or 'tls/host:7447' would be signed as a DNS name no client matches,
    and TLS would fail on the far machine, not here."""
    if not host:
        return
    try:
        ipaddress.ip_address(host)
        return
    except ValueError:
        pass
    name = host.removeprefix("*.").removesuffix(".")  # a wildcard, a fully qualified name
    if len(name) <= 253 and all(_LABEL.fullmatch(label) for label in name.split(".")):
        return
    why = ("give the host alone, without the protocol" if "/" in host
           else "give the host without the port" if ":" in host
           else "not an IP address or a host name (letters, digits, '-' and '.')")
    raise CliError(f"--router {spec!r}: host {host!r}: {why}")


"""Throwaway TLS certificates for the tests, made at test time with the ``openssl`` command line:
a CA and certificates signed by it for 127.0.0.1 / localhost, each valid two days. Nothing here
is committed: every test makes its own in a temporary folder."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

__all__ = ["make_certs", "ROOT", "ZENOH_EXAMPLES"]

ROOT = Path(__file__).resolve().parents[2]
#: the example zenoh configs shipped with mapinterp
ZENOH_EXAMPLES = ROOT / "scenarios" / "zenoh"

_EXT = (
    "subjectAltName=IP:127.0.0.1,DNS:localhost\n"
    "extendedKeyUsage=serverAuth,clientAuth\n"
    "basicConstraints=CA:FALSE\n"
    "keyUsage=critical,digitalSignature\n"
)


def _openssl(*args: str, cwd: Path) -> None:
    done = subprocess.run(["openssl", *args], cwd=cwd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def make_certs(folder: Path, names: tuple[str, ...] = ("run", "agent", "intruder")) -> Path:
    """``folder/certs/``: ``ca.pem`` (CN mapinterp-test-ca) and per name ``NAME.pem`` /
    ``NAME-key.pem`` (CN ``mapinterp-NAME``), the layout the example configs in
    scenarios/zenoh/ read (relative to the folder mapinterp runs in). Skips without openssl."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is needed to make test certificates")
    certs = folder / "certs"
    certs.mkdir(parents=True, exist_ok=True)
    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes")
    _openssl(
        "req", "-x509", *ec, "-keyout", "ca-key.pem", "-out", "ca.pem", "-days", "2",
        "-subj", "/CN=mapinterp-test-ca",
        "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign",
        cwd=certs,
    )  # fmt: skip
    (certs / "ext.cnf").write_text(_EXT)
    for name in names:
        _openssl(
            "req", *ec, "-keyout", f"{name}-key.pem", "-out", f"{name}.csr", "-subj", f"/CN=mapinterp-{name}", cwd=certs
        )
        _openssl(
            "x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem", "-CAcreateserial",
            "-out", f"{name}.pem", "-days", "2", "-extfile", "ext.cnf",
            cwd=certs,
        )  # fmt: skip
    return certs

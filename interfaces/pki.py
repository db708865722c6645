"""A development certificate authority for the Zenoh links: `bof-certs DIR`.

    bof-certs DIR [--roles plant target companion gcs] [--days N] [--force]

Writes into DIR (created with mode 0700):

    ca.pem            the CA certificate every process trusts (public)
    ca.key            the CA's private key (mode 0600; only needed to issue more certificates)
    <role>.pem        one certificate per role, common name = the role
    <role>.key        its private key (mode 0600, unencrypted PKCS#8: Zenoh reads it as is)

Each process presents its role's certificate on every Zenoh TLS link (mutual TLS), and the
Zenoh access-control rules (`interfaces.zenoh_transport.access_control`) grant what each role
may publish by that common name. Keys are ECDSA P-256 with SHA-256 signatures (accepted by the
rustls that Zenoh uses). Every role certificate names ``127.0.0.1``, ``::1`` and ``localhost``
as subject alternative names, so the TLS name check passes on loopback, and carries both the
server and client extended key usages (a Zenoh peer both listens and connects).

This is a **development** CA: the CA key sits beside the certificates, on the same machine.
A real deployment issues certificates from a CA whose key never leaves a protected host,
puts the aircraft's real addresses in the subject alternative names, and installs on each
machine only ca.pem and that machine's own certificate and key.
"""

from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import os
import re
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from interfaces.cli import CommandParser

#: The identities of the bearing-follow processes (certificate common names).
ROLES = ("plant", "target", "companion", "gcs")
CA_CERTIFICATE = "ca.pem"
CA_KEY = "ca.key"
#: Default validity of the certificates, days.
DEFAULT_DAYS = 30
MAX_DAYS = 3650
_ROLE = re.compile(r"[a-z0-9][a-z0-9_\-]{0,31}")
_ORGANIZATION = "bearing-follow development"
#: Certificates are valid from this long before they are made (clocks of peers may lag a little).
_BACKDATE = dt.timedelta(minutes=5)


class PkiError(RuntimeError):
    """The certificates could not be written or read; the message says why in one line."""


@dataclass(frozen=True)
class Identity:
    """What one process needs for mutual TLS: the CA to trust, its certificate and its key (paths)."""

    role: str
    ca: Path
    certificate: Path
    key: Path


def check_role(role: str) -> str:
    """`role` if it is a valid role name (1-32 of a-z 0-9 _ -, starting with a letter or digit), else PkiError."""
    if not isinstance(role, str) or not _ROLE.fullmatch(role):
        raise PkiError(f"role {role!r}: use 1-32 characters from a-z 0-9 _ - (it becomes the certificate common name)")
    return role


def identity(folder: Path, role: str, now: dt.datetime | None = None) -> Identity:
    """The identity of `role` in a folder made by `make_pki` (or laid out the same way), checked.

    PkiError (one line) if a file is missing or unreadable, if the certificate's common name
    is not `role`, if it was not issued by ca.pem, if the key does not belong to it, or if it
    is not valid at `now` (UTC; default the clock): all things a peer would otherwise refuse
    silently, leaving this process alone on the network.
    """
    folder = Path(folder).absolute()  # Zenoh opens the files later, perhaps from another working folder
    check_role(role)
    found = Identity(role, folder / CA_CERTIFICATE, folder / f"{role}.pem", folder / f"{role}.key")
    for path in (found.ca, found.certificate, found.key):
        if not path.is_file():
            raise PkiError(f"{path}: missing (make the certificates with: bof-certs {folder})")
        if not os.access(path, os.R_OK):
            raise PkiError(f"{path}: not readable by this user")
    ca, certificate = _load_certificate(found.ca), _load_certificate(found.certificate)
    try:
        key = serialization.load_pem_private_key(found.key.read_bytes(), password=None)
    except (ValueError, TypeError) as error:
        raise PkiError(f"{found.key}: not an unencrypted PEM private key ({error})") from None
    common_name = certificate_common_name(found.certificate)
    if common_name != role:
        raise PkiError(f"{found.certificate}: common name {common_name!r}, expected the role {role!r}")
    try:
        certificate.verify_directly_issued_by(ca)
    except (ValueError, TypeError, InvalidSignature):
        raise PkiError(f"{found.certificate}: not issued by the CA in {found.ca}") from None
    if key.public_key().public_bytes(serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo) != \
            certificate.public_key().public_bytes(serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo):
        raise PkiError(f"{found.key}: this key does not belong to {found.certificate}")
    moment = now or dt.datetime.now(dt.timezone.utc)
    for path, cert in ((found.ca, ca), (found.certificate, certificate)):
        if not cert.not_valid_before_utc <= moment <= cert.not_valid_after_utc:
            raise PkiError(f"{path}: valid from {cert.not_valid_before_utc:%Y-%m-%d %H:%M} to "
                           f"{cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC, not now (make new ones with bof-certs)")
    return found


def _load_certificate(path: Path) -> x509.Certificate:
    try:
        return x509.load_pem_x509_certificate(Path(path).read_bytes())
    except (OSError, ValueError) as error:
        raise PkiError(f"{path}: not a readable PEM certificate ({error})") from None


def certificate_common_name(path: Path) -> str:
    """The subject common name of the PEM certificate at `path`."""
    certificate = _load_certificate(path)
    names = certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    if not names:
        raise PkiError(f"{path}: the certificate has no common name")
    return str(names[0].value)


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, _ORGANIZATION),
                      x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())


def _write(path: Path, data: bytes, mode: int) -> None:
    """Write `data` to a new file with permissions `mode` from the start (never world-readable, even briefly)."""
    path.unlink(missing_ok=True)
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(descriptor, "wb") as file:
        file.write(data)
    os.chmod(path, mode)  # the umask may have removed bits from `mode`; set exactly what was asked


def make_pki(folder: Path, roles: Iterable[str] = ROLES, days: int = DEFAULT_DAYS, force: bool = False,
             now: dt.datetime | None = None) -> dict[str, Identity]:
    """Make a development CA and one certificate per role in `folder`; returns role -> Identity.

    folder: created (mode 0700) if absent; if it exists and is not empty, PkiError unless
    `force` (then the CA and the role files are replaced; other files are left alone).
    days: validity from now (1..3650). now: the issuing time (UTC; default the clock).
    """
    folder = Path(folder)
    roles = list(dict.fromkeys(check_role(role) for role in roles))
    if not roles:
        raise PkiError("no roles given")
    if isinstance(days, bool) or not isinstance(days, int) or not 1 <= days <= MAX_DAYS:
        raise PkiError(f"--days {days!r}: expected a whole number of days within [1, {MAX_DAYS}]")
    if folder.exists() and not folder.is_dir():
        raise PkiError(f"{folder}: exists and is not a folder")
    if folder.is_dir() and any(folder.iterdir()) and not force:
        raise PkiError(f"{folder}: exists and is not empty; pass --force to replace its certificates")
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as error:
        raise PkiError(f"{folder}: cannot create the folder ({error.strerror})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PkiError(f"{folder}: not writable by this user")
    start = (now or dt.datetime.now(dt.timezone.utc)) - _BACKDATE
    end = start + _BACKDATE + dt.timedelta(days=days)

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = _name("bearing-follow development CA")
    ca_ski = x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key())
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(start).not_valid_after(end)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False, key_cert_sign=True, crl_sign=True,
                                       encipher_only=False, decipher_only=False), critical=True)
          .add_extension(ca_ski, critical=False)
          .sign(ca_key, hashes.SHA256()))
    issued: dict[str, Identity] = {}
    try:
        _write(folder / CA_KEY, _key_pem(ca_key), 0o600)
        _write(folder / CA_CERTIFICATE, ca.public_bytes(serialization.Encoding.PEM), 0o644)
        for role in roles:
            key = ec.generate_private_key(ec.SECP256R1())
            certificate = (
                x509.CertificateBuilder().subject_name(_name(role)).issuer_name(ca_name).public_key(key.public_key())
                .serial_number(x509.random_serial_number()).not_valid_before(start).not_valid_after(end)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                             data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                             crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                               critical=False)
                .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                            x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
                                                            x509.IPAddress(ipaddress.ip_address("::1"))]), critical=False)
                .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
                .add_extension(x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(ca_ski), critical=False)
                .sign(ca_key, hashes.SHA256()))
            _write(folder / f"{role}.key", _key_pem(key), 0o600)
            _write(folder / f"{role}.pem", certificate.public_bytes(serialization.Encoding.PEM), 0o644)
            issued[role] = Identity(role, folder / CA_CERTIFICATE, folder / f"{role}.pem", folder / f"{role}.key")
    except OSError as error:
        raise PkiError(f"{error.filename or folder}: cannot write ({error.strerror})") from None
    return issued


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `bof-certs` (the CLI reference page prints its help)."""
    parser = CommandParser(prog="bof-certs", description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, metavar="DIR", help="folder to create for the CA and the certificates")
    parser.add_argument("--roles", nargs="+", default=list(ROLES), metavar="ROLE",
                        help="roles to issue a certificate for (default: %(default)s)")
    parser.add_argument("--days", type=int, default=DEFAULT_DAYS,
                        help=f"validity of the certificates in days, 1..{MAX_DAYS} (default: %(default)s)")
    parser.add_argument("--force", action="store_true",
                        help="replace the CA and certificates in a folder that is not empty (default: refuse)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        issued = make_pki(args.folder, args.roles, args.days, args.force)
    except PkiError as error:
        print(f"bof-certs: {error}", file=sys.stderr)
        return 2
    print(f"bof-certs: development CA {args.folder / CA_CERTIFICATE}; certificates for {', '.join(issued)}, "
          f"valid {args.days} days (keys are mode 0600; development use only)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

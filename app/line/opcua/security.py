"""Who may talk to the OPC UA server and how (docs/opcua.md "Security").

- With a security policy the server offers only that policy in SignAndEncrypt mode, with its own
  self-signed application certificate, created on first start in the state directory
  (`opcua/server-cert.der`, key `opcua/server-key.pem` 0600; made again when expired or when
  the application URI changed). A client is accepted only with a certificate in
  `opcua/trusted/` (DER or PEM, the exact certificate: the usual OPC UA trust list; CA chains
  are not followed), checked when the client opens its secure channel (the transport guard
  asks `TrustValidator.channel_refusal`) and again at CreateSession; a refused one is written to
  `opcua/rejected/` (MAX_REJECTED at most, the oldest removed) so that an administrator can
  move it to `trusted/` (it takes effect at the client's next connection).
- Anonymous sessions: on loopback always; beyond loopback only with `[opcua] allow_anonymous`
  (still over a trusted, encrypted channel). Otherwise a session needs an X509 user identity
  that is in `trusted/`. No user names and passwords.
- Every variable is read-only and the address space cannot be changed: the only request that
  changes anything is the Acknowledge method, itself refused unless `[opcua] allow_ack`.
  `caller()` names the session's user for the audit of that method (its certificate's common
  name, or "anonymous").
"""

from __future__ import annotations

import contextvars
import datetime as dt
import ipaddress
import logging
import os
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Any

from asyncua import Server, ua
from asyncua.common.utils import ServiceError
from asyncua.crypto import cert_gen, uacrypto
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from app.config.endpoint import is_loopback, split_endpoint
from app.errors import InputError
from app.line.statedir import StateDir

if TYPE_CHECKING:
    from app.config.line import OpcUaSettings  # (the server process does not import it)

log = logging.getLogger("rvis.line.opcua")

CERT_DAYS = 5 * 365
KEY_MODE = 0o600
MAX_REJECTED = 100  # certificates kept in rejected/ (a peer can send any number)
_CALLER: contextvars.ContextVar[str] = contextvars.ContextVar("opcua_caller", default="unknown")
_CALL = ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)
#: every request of a client that only reads: asyncua's user requests but Write
_ALLOWED = frozenset(
    ua.NodeId(i) for i in USER_TYPES if i != ua.ObjectIds.WriteRequest_Encoding_DefaultBinary
)


def caller() -> str:
    """The user of the request being served (set when a method call is let through)."""
    return _CALLER.get()


class ReadOnlyRules(PermissionRuleset):
    """Reads, browses, subscriptions and method calls; no writes, no node management."""

    def check_validity(self, user: Any, action_type_id: Any, body: Any) -> bool:
        if action_type_id not in _ALLOWED:
            return False
        if action_type_id == _CALL:
            _CALLER.set(str(getattr(user, "name", None) or "anonymous"))
        return True


def _der_files(folder: Path) -> list[bytes]:
    """The certificates in `folder` (DER or PEM), as DER; unreadable files are skipped."""
    out = []
    for path in sorted(folder.glob("*")) if folder.is_dir() else []:
        try:
            data = path.read_bytes()
            cert = (
                x509.load_pem_x509_certificate(data)
                if data.lstrip().startswith(b"-----")
                else x509.load_der_x509_certificate(data)
            )
        except (OSError, ValueError) as exc:
            log.warning("OPC UA trusted certificate %s skipped: %s", path, exc)
            continue
        out.append(cert.public_bytes(Encoding.DER))
    return out


def common_name(der: bytes) -> str:
    cert = x509.load_der_x509_certificate(der)
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if names else cert.fingerprint(uacrypto.hashes.SHA1()).hex()


def _listing(folder: Path) -> tuple[tuple[str, int, int], ...]:
    """The files of `folder` as (name, mtime [ns], size): a change to any makes another."""
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return ()
    out = []
    for entry in entries:
        try:
            st = entry.stat()
        except OSError:
            continue
        out.append((entry.name, st.st_mtime_ns, st.st_size))
    return tuple(sorted(out))


def first_certificate(data: bytes) -> bytes:
    """The first certificate of a DER chain (a SenderCertificate may carry its issuers after it;
    `data` itself when its length cannot be read)."""
    if len(data) < 2 or data[0] != 0x30:
        return data
    if data[1] < 0x80:
        return data[: 2 + data[1]]
    n = data[1] & 0x7F
    return data[: 2 + n + int.from_bytes(data[2 : 2 + n], "big")]


class TrustList:
    """The trusted client certificates (read again whenever the folder changed, so a
    certificate moved there takes effect at the next connection), the rejected ones kept."""

    def __init__(self, paths: StateDir) -> None:
        self.trusted, self.rejected = paths.opcua_trusted, paths.opcua_rejected
        self._read: tuple[tuple[tuple[str, int, int], ...], frozenset[bytes]] | None = None

    def contains(self, der: bytes) -> bool:
        listing = _listing(self.trusted)
        if self._read is None or self._read[0] != listing:
            self._read = (listing, frozenset(_der_files(self.trusted)))
        return der in self._read[1]

    def reject(self, der: bytes) -> None:
        """`der` kept in rejected/ (once; at most MAX_REJECTED there, the oldest removed)."""
        name = x509.load_der_x509_certificate(der).fingerprint(uacrypto.hashes.SHA1()).hex()
        path = self.rejected / f"{common_name(der)} [{name}].der".replace("/", "_")
        if path.is_file():
            return
        try:
            self.rejected.mkdir(parents=True, exist_ok=True)
            path.write_bytes(der)
            kept = sorted(self.rejected.glob("*.der"), key=lambda p: p.stat().st_mtime_ns)
            for old in kept[:-MAX_REJECTED]:
                old.unlink(missing_ok=True)
        except OSError as exc:
            log.warning("cannot keep the rejected certificate in %s: %s", self.rejected, exc)


class TrustedUsers:
    """asyncua's user manager: a session's certificate (the X509 identity, or the secure
    channel's for an anonymous identity) must be trusted; anonymous without one only on an
    unsecured (loopback) endpoint."""

    def __init__(self, trust: TrustList, secure: bool) -> None:
        self.trust, self.secure = trust, secure

    def get_user(
        self,
        iserver: Any,
        username: str | None = None,
        password: str | None = None,
        certificate: Any = None,
    ) -> User | None:
        if username is not None:
            return None  # no user names and passwords
        if not certificate:  # none (b"" from an unsecured channel)
            return None if self.secure else User(role=UserRole.User, name="anonymous")
        der = certificate if isinstance(certificate, bytes) else uacrypto.der_from_x509(certificate)
        if not self.trust.contains(der):
            self.trust.reject(der)
            return None
        return User(role=UserRole.User, name=common_name(der))


class TrustValidator:
    """The client certificate when it opens its secure channel (`channel_refusal`: trusted) and
    at session creation (time range, application URI, trusted)."""

    def __init__(self, trust: TrustList) -> None:
        self.trust = trust
        self.basic = CertificateValidator(
            CertificateValidatorOptions.BASIC_VALIDATION | CertificateValidatorOptions.PEER_CLIENT
        )

    async def __call__(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        der = cert.public_bytes(Encoding.DER)
        try:
            await self.basic.validate(cert, app)
            if not self.trust.contains(der):
                raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
        except ServiceError:
            log.warning(
                "OPC UA client %s (%s) refused: its certificate is not in %s",
                app.ApplicationUri,
                common_name(der),
                self.trust.trusted,
            )
            self.trust.reject(der)
            raise

    def channel_refusal(self, sender: bytes | None) -> str:
        """Why an OpenSecureChannel with this SenderCertificate is refused ("": it is not): a
        certificate not in trusted/ (kept in rejected/), an unreadable one, none."""
        if not sender:
            return "an OpenSecureChannel without a sender certificate"
        der = first_certificate(sender)
        try:
            name = common_name(der)
        except ValueError as exc:
            return f"an unreadable sender certificate: {exc}"
        if self.trust.contains(der):
            return ""
        self.trust.reject(der)
        return f"certificate {name!r} is not trusted (not in {self.trust.trusted.name}/)"


POLICY_TYPES = {
    "Basic256Sha256": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    "Aes128Sha256RsaOaep": ua.SecurityPolicyType.Aes128Sha256RsaOaep_SignAndEncrypt,
    "Aes256Sha256RsaPss": ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt,
}


def user_manager(settings: OpcUaSettings, paths: StateDir) -> TrustedUsers:
    return TrustedUsers(TrustList(paths), settings.security_policy != "none")


async def secure(server: Server, settings: OpcUaSettings, paths: StateDir, app_uri: str) -> None:
    """Endpoints, identities, certificates and permissions of `server` (before start)."""
    host, _port = split_endpoint(settings.endpoint)
    rules = ReadOnlyRules()
    tokens: list[type] = [ua.X509IdentityToken]
    if is_loopback(host) or settings.allow_anonymous:
        tokens.append(ua.AnonymousIdentityToken)
    server.set_identity_tokens(tokens)
    if settings.security_policy == "none":
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity], rules)
        return
    cert, key = server_certificate(paths, app_uri, host)
    await server.load_certificate(str(cert))
    await server.load_private_key(str(key))
    server.set_security_policy([POLICY_TYPES[settings.security_policy]], rules)
    server.set_certificate_validator(TrustValidator(TrustList(paths)))


def server_certificate(paths: StateDir, app_uri: str, host: str) -> tuple[Path, Path]:
    """The server's certificate and key, created when missing, expired or for another
    application URI; InputError when the state directory cannot hold them."""
    cert_path, key_path = paths.opcua_cert, paths.opcua_key
    try:
        paths.opcua_trusted.mkdir(parents=True, exist_ok=True)
        if _usable(cert_path, key_path, app_uri):
            return cert_path, key_path
        key = cert_gen.generate_private_key()
        names: list[x509.GeneralName] = [
            x509.UniformResourceIdentifier(app_uri),
            x509.DNSName(socket.gethostname()),
        ]
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
        cert = cert_gen.generate_self_signed_app_certificate(
            key,
            app_uri,
            {},
            names,
            extended=[ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
            days=CERT_DAYS,
        )
        _write(key_path, cert_gen.dump_private_key_as_pem(key), KEY_MODE)
        _write(cert_path, cert.public_bytes(Encoding.DER), 0o640)
    except OSError as exc:
        raise InputError(f"cannot keep the OPC UA certificate: {exc}", file=paths.opcua) from exc
    log.info("OPC UA server certificate created: %s (%s)", cert_path, app_uri)
    return cert_path, key_path


def _usable(cert_path: Path, key_path: Path, app_uri: str) -> bool:
    if not (cert_path.is_file() and key_path.is_file()):
        return False
    try:
        cert = x509.load_der_x509_certificate(cert_path.read_bytes())
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except (ValueError, x509.ExtensionNotFound):
        log.warning("OPC UA server certificate %s unreadable: made again", cert_path)
        return False
    if app_uri not in san.get_values_for_type(x509.UniformResourceIdentifier):
        log.warning("OPC UA server certificate %s is for another application URI", cert_path)
        return False
    if cert.not_valid_after_utc <= dt.datetime.now(dt.UTC):
        log.warning("OPC UA server certificate %s expired: made again", cert_path)
        return False
    return True


def _write(path: Path, data: bytes, mode: int) -> None:
    """Write atomically with `mode` (the key is never readable by others, not even briefly)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)

"""Who may open a session, and what any session may do: read, browse and subscribe;
never write, call methods or change the address space (every user is read-only)."""

from __future__ import annotations

import hmac

from asyncua import ua
from asyncua.crypto.truststore import TrustStore
from cryptography import x509
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole

from api.service.config.settings import OpcuaSettings

_REFUSED = (ua.ObjectIds.WriteRequest_Encoding_DefaultBinary, ua.ObjectIds.CallRequest_Encoding_DefaultBinary)


class ReadOnlyRuleset(PermissionRuleset):
    """Every role, the same read-only requests: asyncua's own ruleset lets users write and
    anonymous sessions do nothing at all."""

    def __init__(self) -> None:
        self._allowed = {ua.NodeId(t) for t in USER_TYPES if t not in _REFUSED}

    def check_validity(self, user, action_type_id, body) -> bool:
        return action_type_id in self._allowed


class Users:
    """asyncua's user manager: anonymous sessions when allowed, and the configured user.
    None refuses the session (BadUserAccessDenied)."""

    def __init__(self, settings: OpcuaSettings, trust_store: TrustStore | None = None):
        self.anonymous = settings.anonymous
        self.username = settings.username
        self.password = settings.password
        self.trust_store = trust_store  # loaded: client certificates trusted as users

    def trusted(self, certificate: bytes | None) -> str | None:
        """The common name of a trusted certificate (DER), None if it is not trusted."""
        if not certificate or self.trust_store is None:
            return None
        try:
            cert = x509.load_der_x509_certificate(certificate)
        except ValueError:
            return None
        if not self.trust_store.validate(cert):
            return None
        cn = cert.subject.get_attributes_for_oid(x509.OID_COMMON_NAME)
        return str(cn[0].value) if cn else "certificate"

    def get_user(self, iserver, username=None, password=None, certificate=None) -> User | None:
        # ``certificate`` is the X509 identity token's certificate, or else the secure
        # channel's client certificate (asyncua passes either): a trusted one is a user.
        # With a trust store only signed channels are offered (server.security_policies),
        # so the client has proven it holds the certificate's key.
        if username is None:
            if self.anonymous:
                return User(role=UserRole.Anonymous)
            name = self.trusted(certificate)
            return User(role=UserRole.User, name=name) if name is not None else None
        if self.username is None or self.password is None:
            return None
        ok = hmac.compare_digest(username.encode(), self.username.encode())
        ok &= hmac.compare_digest((password or "").encode(), self.password.encode())
        return User(role=UserRole.User, name=username) if ok else None

    def identity_tokens(self) -> list[type]:
        tokens: list[type] = []
        if self.anonymous or self.trust_store is not None:  # with a trust store: the channel's certificate identifies
            tokens.append(ua.AnonymousIdentityToken)
        if self.username is not None:
            tokens.append(ua.UserNameIdentityToken)
        if self.trust_store is not None:
            tokens.append(ua.X509IdentityToken)
        return tokens

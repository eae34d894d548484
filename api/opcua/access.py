"""Who may open a session, and what any session may do: read, browse and subscribe;
never write, call methods or change the address space (every user is read-only)."""

from __future__ import annotations

import hmac

from asyncua import ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole

from api.service.config import OpcuaSettings

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

    def __init__(self, settings: OpcuaSettings):
        self.anonymous = settings.anonymous
        self.username = settings.username
        self.password = settings.password

    def get_user(self, iserver, username=None, password=None, certificate=None) -> User | None:
        # ``certificate`` is the secure channel's peer certificate for every token type, not
        # an identity: X509 identity tokens are not offered (identity_tokens), so no
        # username means an anonymous session.
        if username is None:
            return User(role=UserRole.Anonymous) if self.anonymous else None
        if self.username is None or self.password is None:
            return None
        ok = hmac.compare_digest(username.encode(), self.username.encode())
        ok &= hmac.compare_digest((password or "").encode(), self.password.encode())
        return User(role=UserRole.User, name=username) if ok else None

    def identity_tokens(self) -> list[type]:
        tokens: list[type] = []
        if self.anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        if self.username is not None:
            tokens.append(ua.UserNameIdentityToken)
        return tokens

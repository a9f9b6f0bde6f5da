"""Users of the service: their passwords (argon2id, argon2-cffi's defaults of RFC 9106), API tokens and sessions,
and the audit entry every change of state appends (:func:`audit`). The records live in the run store
(:mod:`tcms_daq.store.people`); the rights of each role in :mod:`tcms_daq.service.auth`."""

from __future__ import annotations

import secrets

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError, VerifyMismatchError

from tcms_daq.errors import ConfigError
from tcms_daq.service.auth import Principal
from tcms_daq.store import Store

MIN_PASSWORD_CHARS = 8
_hasher = PasswordHasher()
# a hash to verify against when the user does not exist, so a wrong name costs the same time as a wrong password
_DUMMY_HASH = _hasher.hash(secrets.token_urlsafe(16))


def hash_password(password: str) -> str:
    """An argon2id hash of ``password`` (a fresh salt each time); ConfigError for one shorter than 8 characters."""
    if len(password) < MIN_PASSWORD_CHARS:
        raise ConfigError(f"a password needs at least {MIN_PASSWORD_CHARS} characters")
    return _hasher.hash(password)


def verify_password(password: str, hashed: str | None) -> bool:
    """Whether ``password`` matches ``hashed`` (False for None or a malformed hash, never an exception)."""
    try:
        return _hasher.verify(hashed or _DUMMY_HASH, password) and hashed is not None
    except (VerifyMismatchError, VerificationError, InvalidHashError):
        return False


def check_login(store: Store, name: str, password: str) -> bool:
    """Whether ``name`` is an enabled user whose password is ``password`` (an unknown name takes as long)."""
    user = store.user(name)
    ok = verify_password(password, store.password_hash(name) if user is not None else None)
    return ok and user is not None and not user.disabled


def new_secret() -> str:
    """A new API token or session id: 256 random bits, URL-safe."""
    return secrets.token_urlsafe(32)


def new_api_token(store: Store, name: str, label: str = "") -> str:
    """A new API token of user ``name``, kept as its hash; the token itself is shown once."""
    token = "tcms_" + new_secret()
    store.add_api_token(name, token, label)
    return token


def audit(store: Store, who: Principal | str, action: str, *, target: str | None = None,
          before: object = None, after: object = None, detail: str | None = None) -> None:
    """Append one entry to the audit trail: ``who`` (a principal, or a name such as ``cli:alice``) did
    ``action`` on ``target``; ``before``/``after``: the version or hash it changed from and to."""
    name, role = (who.name, who.role) if isinstance(who, Principal) else (who, None)
    store.append_audit(name, action, role=role, target=target,
                       before=None if before is None else str(before), after=None if after is None else str(after),
                       detail=detail)

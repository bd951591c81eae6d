"""Who may connect: bind-address policy and constant-time token checks."""

from __future__ import annotations

import hmac
import ipaddress
from urllib.parse import parse_qs, urlsplit

LOOPBACK_NAMES = {"localhost", "ip6-localhost"}


class InsecureBindError(ValueError):
    pass


def is_loopback(host: str) -> bool:
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name we cannot vouch for


def check_bind(host: str, token: str) -> None:
    """Refuse to start a token-less server on anything but loopback (DESIGN.md §5)."""
    if not token and not is_loopback(host):
        raise InsecureBindError(
            f"refusing to bind {host!r} without a token: set the `token` parameter or its environment "
            "variable, or bind 127.0.0.1"
        )


def presented_token(authorization: str | None, path: str) -> str | None:
    """The token a client presented: `Authorization: Bearer <t>` header, else `?token=<t>` in the URL."""
    if authorization:
        scheme, _, value = authorization.strip().partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            return value.strip()
    values = parse_qs(urlsplit(path).query).get("token")
    return values[0] if values else None


def token_matches(expected: str, presented: str | None) -> bool:
    """True when no token is required, or the presented one equals it (constant-time compare)."""
    if not expected:
        return True
    if presented is None:
        return False
    return hmac.compare_digest(expected.encode("utf-8"), presented.encode("utf-8"))

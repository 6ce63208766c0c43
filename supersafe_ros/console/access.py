"""Who may talk to the console, without aiohttp: the Host and Origin rules and the token.

DNS rebinding: a web site the participant (or anyone on a shared machine) opens can
point its own host name at 127.0.0.1 and then load the console's page and open its
WebSocket as a "same-origin" page of that name. Two checks stop it, on every request:

* ``Host`` must name the console itself: 127.0.0.1, localhost, [::1] or the address it
  is bound to (with a wildcard bind, 0.0.0.0 or ::, any IP address literal: an address
  cannot be rebound, only a name can);
* ``Origin``, when a browser sends one, must be http(s) on one of those same names and
  the port the request came to (a page of the console itself).

Bound to any other than a loopback address, every request also needs the token.
"""
from __future__ import annotations

import ipaddress
from urllib.parse import urlsplit

LOOPBACK_NAMES = ('127.0.0.1', 'localhost', '::1')
WILDCARDS = ('0.0.0.0', '::', '')


def is_loopback(host: str) -> bool:
    if host == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return False


class HostRules:
    """The names a request may use for a console bound to ``bind_host``."""

    def __init__(self, bind_host: str):
        self.bind_host = (bind_host or '').strip('[]').lower()
        self.wildcard = self.bind_host in WILDCARDS
        self.names = set(LOOPBACK_NAMES) | ({self.bind_host} if not self.wildcard else set())

    def name_allowed(self, name: str | None) -> bool:
        if not name:
            return False
        name = name.strip('[]').lower().rstrip('.')
        return name in self.names or (self.wildcard and _is_ip(name))

    @staticmethod
    def _split(netloc: str):
        """'name:port' or '[v6]:port' -> (name, port or None); raises ValueError if malformed."""
        parts = urlsplit('//' + netloc)
        return parts.hostname, parts.port

    def host_ok(self, host_header: str | None) -> bool:
        """The Host header names this console (any port: a proxy or a tunnel may map it)."""
        if not host_header:
            return False
        try:
            name, _ = self._split(host_header)
        except ValueError:
            return False
        return self.name_allowed(name)

    def origin_ok(self, origin: str | None, host_header: str | None) -> bool:
        """No Origin (not a browser page: scripts, tests), or a page of this console: an
        allowed name, on the port of the request's Host."""
        if origin is None:
            return True
        try:
            parts = urlsplit(origin)
            default = {'http': 80, 'https': 443}.get(parts.scheme)
            port = parts.port or default
            _, host_port = self._split(host_header or '')
        except ValueError:
            return False
        return (default is not None and self.name_allowed(parts.hostname)
                and port == (host_port or default))

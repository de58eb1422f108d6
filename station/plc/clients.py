"""Which Modbus TCP clients may connect, and which of them may only read: ``plc.allowed_clients``.

An entry is an IP address or network, optionally followed by its access:

    allowed_clients:
      - 10.0.0.10              # the line PLC: reads and writes (the default access, "write")
      - 10.0.0.0/24 read       # the shop's MES and dashboards: may read, never start a cycle

An empty list lets any client that can reach the bound address read and write. A client that no
entry covers is refused. A client covered by several entries gets the access of the most
specific one (the longest prefix), so ``0.0.0.0/0`` with ``10.0.0.5 read`` lets everyone write
but 10.0.0.5; two entries for the same network with different access are a configuration error.
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass
from enum import Enum

from station.errors import ConfigError

HINT = ('write entries like "10.0.0.5", "10.0.0.0/24" or "10.0.0.5 read" '
        '(read: may only read; write, the default: may read and write)')


class Access(Enum):
    REFUSED = "refused"
    READ = "read"
    WRITE = "write"


@dataclass(frozen=True)
class ClientRule:
    network: ipaddress.IPv4Network | ipaddress.IPv6Network
    access: Access
    entry: str  # as written in the configuration, for messages


def parse_rule(entry) -> ClientRule:
    """One ``plc.allowed_clients`` entry -> its rule; raises ConfigError naming a bad entry."""
    words = str(entry).split()
    if not 1 <= len(words) <= 2:
        raise ConfigError(f"plc.allowed_clients: {entry!r} is not an IP address or network with an "
                          "optional access", hint=HINT)
    try:
        network = ipaddress.ip_network(words[0], strict=False)
    except ValueError:
        raise ConfigError(f"plc.allowed_clients: {words[0]!r} is not an IP address or network",
                          hint=HINT) from None
    access = words[1].lower() if len(words) == 2 else "write"
    if access not in ("read", "write"):
        raise ConfigError(f"plc.allowed_clients: {entry!r}: the access is {words[1]!r}, not read or write",
                          hint=HINT)
    return ClientRule(network, Access(access), str(entry))


class ClientAccess:
    """The parsed allow-list: :meth:`of` an address -> :class:`Access`."""

    def __init__(self, entries=()):
        self.rules = [parse_rule(e) for e in entries or ()]
        seen: dict = {}
        for rule in self.rules:
            other = seen.setdefault(rule.network, rule)
            if other.access is not rule.access:
                raise ConfigError(f"plc.allowed_clients: {other.entry!r} and {rule.entry!r} give the same "
                                  "network different access", hint="keep one of them")
        # most specific first; the caller's first match wins
        self.rules.sort(key=lambda r: r.network.prefixlen, reverse=True)

    def of(self, address: str) -> tuple[Access, str]:
        """The access of a client at ``address`` and the entry that decided it ("" when the list
        is empty or no entry covers it). An IPv4-mapped IPv6 address counts as IPv4."""
        if not self.rules:
            return Access.WRITE, ""
        try:
            ip = ipaddress.ip_address(address.split("%")[0])
        except ValueError:
            return Access.REFUSED, ""
        ip = getattr(ip, "ipv4_mapped", None) or ip
        for rule in self.rules:
            if ip.version == rule.network.version and ip in rule.network:
                return rule.access, rule.entry
        return Access.REFUSED, ""

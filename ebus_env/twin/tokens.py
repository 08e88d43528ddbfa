"""Access tokens: a bus's write token writes that bus only; a fleet's read token reads that
fleet only. Tokens are random (256 bits, :func:`secrets.token_urlsafe`) and stored as their
SHA-256 hash: a high-entropy secret needs no slow password hash (NIST SP 800-63B, 5.1.1.2
concerns memorised secrets), and the database never holds a usable token."""

from __future__ import annotations

import hashlib
import secrets
import time
from dataclasses import dataclass

import sqlalchemy as sa

from ebus_env.errors import ConfigError
from ebus_env.twin.store import Store, buses, fleets, tokens

PREFIX = "ebt_"


@dataclass(frozen=True)
class Grant:
    """What a token may do: write one bus, or read one fleet."""

    kind: str  # "write" or "read"
    bus: str | None
    fleet: str


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def create(store: Store, *, fleet: str, bus: str | None = None, label: str = "",
           reserve_soc_pct: float | None = None) -> str:
    """A new token: a write token of ``bus`` (created in ``fleet`` when new) or, without
    ``bus``, a read token of ``fleet``. Returns the token; only its hash is stored."""
    if not fleet:
        raise ConfigError("a token belongs to a fleet: give --fleet NAME")
    if bus is not None:
        store.add_bus(bus, fleet, reserve_soc_pct)
    else:
        with store.engine.begin() as conn:
            conn.execute(store.insert(fleets).values(name=fleet).on_conflict_do_nothing())
    token = PREFIX + secrets.token_urlsafe(32)
    with store.engine.begin() as conn:
        conn.execute(tokens.insert().values(
            token_hash=token_hash(token), kind="write" if bus else "read", bus=bus,
            fleet=fleet, label=label, created_at=time.time()))
    return token


def revoke(store: Store, token: str) -> bool:
    with store.engine.begin() as conn:
        done = conn.execute(tokens.update().where(tokens.c.token_hash == token_hash(token))
                            .values(revoked=True))
    return done.rowcount > 0


class Tokens:
    """Looks tokens up by their hash, with a cache: a revoked token stops working within
    ``ttl_s`` (a logger sends every 10 s: a shorter time would send most batches to the
    database for their token); an unknown token is asked again after ``unknown_ttl_s`` (one
    created meanwhile works)."""

    def __init__(self, store: Store, ttl_s: float = 60.0, unknown_ttl_s: float = 5.0):
        self.store, self.ttl_s, self.unknown_ttl_s = store, ttl_s, unknown_ttl_s
        self._cache: dict[str, tuple[float, Grant | None]] = {}

    def cached(self, token: str | None) -> tuple[bool, Grant | None]:
        """(whether the cache knows ``token``, its grant), without the database."""
        if not token:
            return True, None
        hit = self._cache.get(token_hash(token))
        if hit is None:
            return False, None
        age = time.monotonic() - hit[0]
        return age < (self.ttl_s if hit[1] is not None else self.unknown_ttl_s), hit[1]

    def grant(self, token: str | None) -> Grant | None:
        known, grant = self.cached(token)
        if known:
            return grant
        key = token_hash(token)
        with self.store.engine.connect() as conn:
            row = conn.execute(sa.select(tokens.c.kind, tokens.c.bus, tokens.c.fleet,
                                         tokens.c.revoked)
                               .where(tokens.c.token_hash == key)).first()
        grant = None if row is None or row.revoked else Grant(row.kind, row.bus, row.fleet)
        self._cache[key] = (time.monotonic(), grant)
        return grant

    def fleet_of(self, bus: str) -> str | None:
        with self.store.engine.connect() as conn:
            return conn.execute(sa.select(buses.c.fleet).where(buses.c.name == bus)).scalar()

"""Loggers that speak MQTT: the twin subscribes to ``fleet/<bus>/telemetry`` on a broker
(Mosquitto) with QoS 1 and a persistent session (clean session off, a fixed client id), so
the broker keeps the messages that arrive while the twin is away.

A message is a batch as the HTTP ingest takes it: JSON (``{"batch_id": ..., "samples":
[...]}``) or CSV lines with a header. It is acknowledged to the broker (PUBACK) only after
its batch is stored durably (it goes to the twin's writer with the HTTP batches, committed in
groups), in the order the messages came (MQTT 3.1.1, section 4.6); a message the twin cannot
store (the database away) is not acknowledged, and the broker sends it again when the twin
reconnects. A malformed message is acknowledged and refused (nothing stored): the twin keeps
the refusal, with its row and field, in :attr:`Subscriber.refused`. The broker checks each
logger's credentials; its ACL lets the user named for a bus write that bus's topic only
(docs/twin.md gives the broker's config).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque

from ebus_env.errors import ConfigError, EbusError
from ebus_env.twin import ingest as payload

TOPIC = "fleet/+/telemetry"
log = logging.getLogger("ebus_env.twin.mqtt")


def parse_address(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"--mqtt {address}: give host:port, e.g. 127.0.0.1:1883")
    return host, int(port)


class Subscriber:
    """The twin's MQTT client: one per twin process (``client_id`` must differ between
    processes that share a broker)."""

    def __init__(self, twin, address: str, user: str | None = None,
                 password: str | None = None, client_id: str = "ebus-twin"):
        import paho.mqtt.client as mqtt

        self.twin = twin
        self.host, self.port = parse_address(address)
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id,
                                  clean_session=False, manual_ack=True)
        if user:
            self.client.username_pw_set(user, password)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.refused: list[dict] = []
        self.stored = 0
        self.connected = threading.Event()
        self._pending: deque = deque()  # [message, outcome] in arrival order
        self._ack_lock = threading.Lock()

    def _on_connect(self, client, _userdata, _flags, reason, _properties=None):
        if reason.is_failure:
            log.error("the broker refused the twin: %s", reason)
            return
        client.subscribe(TOPIC, qos=1)
        self.connected.set()

    def _on_message(self, client, _userdata, message):
        entry = [message, None]  # None: not stored yet; "ack" or "drop" when it is known
        with self._ack_lock:
            self._pending.append(entry)
        parts = message.topic.split("/")
        bus = parts[1] if len(parts) == 3 else None
        try:
            kind = "application/json" if message.payload.lstrip()[:1] in (b"{", b"[") \
                else "text/csv"
            columns, batch_id = payload.parse_body(message.payload, kind, time.time())
            future = self.twin.submit(bus, payload.batch(columns, batch_id))
        except (payload.PayloadError, EbusError) as exc:
            self._refuse(message, exc)
            self._settle(client, entry, "ack")
            return
        future.add_done_callback(lambda f: self._stored(client, entry, f))

    def _stored(self, client, entry, future) -> None:
        """In the writer's thread, after the commit (or its failure)."""
        message = entry[0]
        exc = future.exception()
        if exc is None:
            self.stored += future.result().stored
            self._settle(client, entry, "ack")
        elif isinstance(exc, (payload.PayloadError, EbusError)):
            self._refuse(message, exc)
            self._settle(client, entry, "ack")
        else:  # the store is away: no PUBACK, the broker sends it again
            log.error("could not store a message on %s (%s); the broker will resend it",
                      message.topic, exc)
            self._settle(client, entry, "drop")

    def _refuse(self, message, exc) -> None:
        self.refused.append({"topic": message.topic, "error": str(exc),
                             "field": getattr(exc, "field", None),
                             "row": getattr(exc, "row", None)})
        log.warning("refused a message on %s: %s", message.topic, exc)

    def _settle(self, client, entry, outcome: str) -> None:
        """Acknowledge the messages whose outcome is known, oldest first, up to the first
        one still being stored."""
        with self._ack_lock:
            entry[1] = outcome
            while self._pending and self._pending[0][1] is not None:
                message, done = self._pending.popleft()
                if done == "ack":
                    client.ack(message.mid, message.qos)

    def start(self) -> None:
        self.client.connect(self.host, self.port, keepalive=30)
        self.client.loop_start()

    def stop(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def publish(address: str, bus: str, body: str | bytes, user: str, password: str,
            client_id: str | None = None, timeout_s: float = 30.0) -> None:
    """Publish one batch as ``bus``'s logger would (QoS 1; returns once the broker has it)."""
    import paho.mqtt.client as mqtt

    host, port = parse_address(address)
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id or f"logger-{bus}")
    client.username_pw_set(user, password)
    client.connect(host, port)
    client.loop_start()
    try:
        info = client.publish(f"fleet/{bus}/telemetry", body, qos=1)
        info.wait_for_publish(timeout=timeout_s)
        if not info.is_published():
            raise ConfigError(f"the broker at {address} did not take the message")
    finally:
        client.loop_stop()
        client.disconnect()

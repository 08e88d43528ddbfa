"""Loggers that speak MQTT: the twin subscribes to ``fleet/<bus>/telemetry`` on a broker
(Mosquitto) with QoS 1 and a persistent session (clean session off, a fixed client id), so
the broker keeps the messages that arrive while the twin is away.

A message is a batch as the HTTP ingest takes it: JSON (``{"batch_id": ..., "samples":
[...]}``) or CSV lines with a header. It is acknowledged to the broker (PUBACK) only after
its batch is stored durably; a message the twin cannot store (the database away) is not
acknowledged, and the broker sends it again. A malformed message is acknowledged and
refused (nothing stored): the twin keeps the refusal, with its row and field, in
:attr:`Subscriber.refused`. The broker checks each logger's credentials; its ACL lets the
user named for a bus write that bus's topic only (docs/twin.md gives the broker's config).
"""

from __future__ import annotations

import logging
import threading
import time

from ebus_env.errors import ConfigError, EbusError
from ebus_env.twin import ingest as payload

TOPIC = "fleet/+/telemetry"
log = logging.getLogger("ebus_env.twin.mqtt")


def parse_address(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"--mqtt {address}: give host:port, e.g. 127.0.0.1:1883")
    return host, int(port)


def decode(body: bytes, now_s: float):
    """A message's checked frame and batch id (JSON or CSV lines)."""
    text = body.lstrip()
    if text[:1] in (b"{", b"["):
        frame, batch_id = payload.from_json(body, now_s)
        return frame, batch_id
    return payload.from_csv(body.decode("utf-8", errors="replace"), now_s), None


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

    def _on_connect(self, client, _userdata, _flags, reason, _properties=None):
        if reason.is_failure:
            log.error("the broker refused the twin: %s", reason)
            return
        client.subscribe(TOPIC, qos=1)
        self.connected.set()

    def _on_message(self, client, _userdata, message):
        parts = message.topic.split("/")
        bus = parts[1] if len(parts) == 3 else None
        try:
            frame, batch_id = decode(message.payload, time.time())
            batch = payload.batch(frame, batch_id)
            receipt = self.twin.ingest(bus, batch)
            self.stored += receipt.stored
        except (payload.PayloadError, EbusError) as exc:
            self.refused.append({"topic": message.topic, "error": str(exc),
                                 "field": getattr(exc, "field", None),
                                 "row": getattr(exc, "row", None)})
            log.warning("refused a message on %s: %s", message.topic, exc)
        except Exception:  # the store is away: no PUBACK, the broker sends it again
            log.exception("could not store a message on %s; the broker will resend it",
                          message.topic)
            return
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

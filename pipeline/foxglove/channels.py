"""Foxglove messages into an open MCAP file: each topic's channel and schema registered once,
with the schema and protobuf encoding that foxglove-sdk gives for the message type."""

from __future__ import annotations

from typing import Any

from mcap.writer import Writer


class FoxgloveChannels:
    def __init__(self, writer: Writer):
        self.writer = writer
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}

    def _channel(self, topic: str, message: Any) -> int:
        if topic not in self._channels:
            schema = type(message).get_schema()
            if schema.name not in self._schemas:
                self._schemas[schema.name] = self.writer.register_schema(
                    name=schema.name, encoding=schema.encoding, data=bytes(schema.data)
                )
            self._channels[topic] = self.writer.register_channel(
                topic=topic, message_encoding=schema.encoding, schema_id=self._schemas[schema.name]
            )
        return self._channels[topic]

    def write(self, topic: str, stamp_ns: int, message: Any) -> None:
        """One message, logged (and published) at `stamp_ns`, as the contract's are."""
        self.writer.add_message(
            channel_id=self._channel(topic, message),
            log_time=int(stamp_ns),
            publish_time=int(stamp_ns),
            data=message.encode(),
            sequence=0,
        )

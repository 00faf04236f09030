#!/usr/bin/env node
// Follows `chaoscope monitor --foxglove` with Foxglove's own WebSocket client library
// (@foxglove/ws-protocol's FoxgloveClient over the `ws` package), as the Foxglove app does:
// subscribes to every channel the server advertises, decodes each message with protobufjs from
// the channel's schema (a base64 FileDescriptorSet, protobufjs/ext/descriptor).
//
// Usage: node live_client.js ws://127.0.0.1:PORT TOPIC...
//   Prints {"subscribed": [...]} each time it subscribes, then, when the server closes the
//   connection, one JSON line {"topics": {topic: {messages, last}}}. Exits 1 unless every TOPIC
//   was advertised and delivered at least one message whose values decode as expected.
"use strict";

const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

// protobufjs names fields in camelCase; back to the proto's names (log10Mean -> log10_mean).
const snake = (name) => name.replace(/[A-Z]/g, (c) => `_${c.toLowerCase()}`);
const snakeKeys = (v) =>
  Array.isArray(v)
    ? v.map(snakeKeys)
    : v && typeof v === "object"
      ? Object.fromEntries(Object.entries(v).map(([k, x]) => [snake(k), snakeKeys(x)]))
      : v;

function fail(message) {
  console.error(`live_client.js: ${message}`);
  process.exit(1);
}

const [url, ...expected] = process.argv.slice(2);
if (!url || expected.length === 0) fail("usage: node live_client.js URL TOPIC...");

// The crate's server speaks `foxglove.sdk.v1` (the client's default, foxglove.websocket.v1, is
// refused with HTTP 400).
const client = new FoxgloveClient({ ws: new WebSocket(url, ["foxglove.sdk.v1"]) });
const channels = new Map(); // subscription id -> { topic, type }
const received = {}; // topic -> { messages, last }

client.on("error", (e) => fail(`socket error: ${e?.message ?? e}`));
client.on("advertise", (advertised) => {
  const ids = [];
  for (const ch of advertised) {
    if (ch.encoding !== "protobuf" || ch.schemaEncoding !== "protobuf") {
      fail(`${ch.topic}: encoding ${ch.encoding}, schema ${ch.schemaEncoding}`);
    }
    const fds = descriptor.FileDescriptorSet.decode(Buffer.from(ch.schema, "base64"));
    const type = protobuf.Root.fromDescriptor(fds).lookupType(ch.schemaName);
    channels.set(client.subscribe(ch.id), { topic: ch.topic, type });
    ids.push(ch.topic);
  }
  console.log(JSON.stringify({ subscribed: [...channels.values()].map((c) => c.topic) }));
});
client.on("message", ({ subscriptionId, data }) => {
  const ch = channels.get(subscriptionId);
  if (!ch) fail(`message on unknown subscription ${subscriptionId}`);
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  const m = snakeKeys(ch.type.toObject(ch.type.decode(bytes), { longs: Number, defaults: true }));
  const r = (received[ch.topic] ??= { messages: 0, last: null });
  r.messages += 1;
  r.last = m;
});
client.on("close", () => {
  console.log(JSON.stringify({ topics: received }));
  for (const topic of expected) {
    const r = received[topic];
    if (!r) fail(`no message on ${topic}`);
    const m = r.last;
    if (!(Number.isFinite(m.t) && m.t > 0)) fail(`${topic}: t = ${m.t}`);
    if (topic === "/chaoscope/reference") {
      if (!m.state.length || !m.state.every(Number.isFinite)) fail(`${topic}: state ${m.state}`);
    } else if (!m.gali.length || !m.gali.every((g) => Number.isFinite(g.log10_mean))) {
      fail(`${topic}: GALI ${JSON.stringify(m.gali)}`);
    }
  }
  process.exit(0);
});

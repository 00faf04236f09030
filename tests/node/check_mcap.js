#!/usr/bin/env node
// Decodes every message of every channel of a chaoscope MCAP file (a recording or a map) with
// Foxglove's reading stack: @mcap/core's indexed reader (chunk CRCs checked) over @mcap/nodejs'
// file handle, @mcap/support's decompressors, and protobufjs building each schema's types from
// the FileDescriptorSet the file carries (protobufjs/ext/descriptor), as Foxglove and Lichtblick
// do. Nothing of chaoscope is used.
//
// Usage: node check_mcap.js FILE.mcap [ANALYZE.json]
//   With ANALYZE.json (the output of `chaoscope analyze FILE.mcap --json`), the last message of
//   every /chaoscope/indicators/<scheme> channel must equal that report.
// Prints one JSON line: message counts per topic. Exits 1 with a message on any failure.
"use strict";

const fs = require("node:fs/promises");
const { McapIndexedReader } = require("@mcap/core");
const { FileHandleReadable } = require("@mcap/nodejs");
const { loadDecompressHandlers } = require("@mcap/support");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

function fail(message) {
  console.error(`check_mcap.js: ${message}`);
  process.exit(1);
}

// uint64 fields decode as Long objects (or numbers): as Numbers, exact below 2^53. protobufjs
// names fields in camelCase (log10Mean); the proto's snake_case names are what Foxglove shows.
const snake = (name) => name.replace(/[A-Z]/g, (c) => `_${c.toLowerCase()}`);
const snakeKeys = (v) =>
  Array.isArray(v)
    ? v.map(snakeKeys)
    : v && typeof v === "object"
      ? Object.fromEntries(Object.entries(v).map(([k, x]) => [snake(k), snakeKeys(x)]))
      : v;
const asObject = (type, bytes) =>
  snakeKeys(type.toObject(type.decode(bytes), { longs: Number, enums: String, defaults: true }));

async function main() {
  const [path, analyzePath] = process.argv.slice(2);
  if (!path) fail("usage: node check_mcap.js FILE.mcap [ANALYZE.json]");
  const handle = await fs.open(path, "r");
  try {
    const reader = await McapIndexedReader.Initialize({
      readable: new FileHandleReadable(handle),
      decompressHandlers: await loadDecompressHandlers(),
    });
    const types = new Map(); // schema id -> protobuf type
    for (const [id, schema] of reader.schemasById) {
      if (schema.encoding !== "protobuf") fail(`schema ${schema.name}: encoding ${schema.encoding}`);
      const root = protobuf.Root.fromDescriptor(descriptor.FileDescriptorSet.decode(schema.data));
      types.set(id, root.lookupType(schema.name));
    }
    const counts = {};
    const lastIndicators = new Map(); // topic -> decoded message
    let total = 0;
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      const channel = reader.channelsById.get(message.channelId);
      if (channel.messageEncoding !== "protobuf") fail(`${channel.topic}: ${channel.messageEncoding}`);
      const decoded = asObject(types.get(channel.schemaId), message.data);
      for (const field of ["state", "separations", "stretch", "x0", "spectrum"]) {
        for (const v of decoded[field] ?? []) {
          if (!Number.isFinite(v)) fail(`non-finite ${field} on ${channel.topic}`);
        }
      }
      counts[channel.topic] = (counts[channel.topic] ?? 0) + 1;
      total += 1;
      if (channel.topic.startsWith("/chaoscope/indicators/")) {
        lastIndicators.set(channel.topic, decoded);
      }
    }
    // Every channel holds messages, and the summary's count is what was decoded.
    for (const channel of reader.channelsById.values()) {
      if (!counts[channel.topic]) fail(`channel ${channel.topic} has no message`);
    }
    const stated = Number(reader.statistics?.messageCount ?? -1n);
    if (stated !== total) fail(`summary states ${stated} messages, decoded ${total}`);
    if (analyzePath) {
      compareIndicators(lastIndicators, JSON.parse(await fs.readFile(analyzePath, "utf8")));
    }
    console.log(JSON.stringify({ total, topics: counts }));
  } finally {
    await handle.close();
  }
}

// The indicators channel against `analyze --json`: the same doubles, bit for bit (JSON numbers
// from serde_json round-trip exactly to the same double). log10 of the mean is compared with
// JavaScript's Math.log10 of the reported mean, which may round differently from the C library's
// log10 in the last place: within 2 units in the last place (the Rust test checks it exactly).
function compareIndicators(last, report) {
  const same = (what, got, want) => {
    if (!Object.is(got, want)) fail(`${what}: indicators channel ${got}, analyze --json ${want}`);
  };
  const mean = (what, got, want) => {
    same(`${what}.mean`, got.mean, want.mean);
    same(`${what}.log10_mean`, got.log10_mean, want.log10_mean);
    const ref = Math.log10(want.mean);
    if (Math.abs(got.log10_of_mean - ref) > 2 * Number.EPSILON * Math.max(1, Math.abs(ref))) {
      fail(`${what}.log10_of_mean: ${got.log10_of_mean} vs Math.log10(mean) = ${ref}`);
    }
  };
  if (!report.schemes.length) fail("the report has no scheme");
  for (const s of report.schemes) {
    const m = last.get(`/chaoscope/indicators/${s.name}`);
    if (!m) fail(`no indicators for scheme ${s.name}`);
    same(`${s.name} t`, m.t, s.t);
    same(`${s.name} sets`, m.sets, s.sets);
    const orders = Object.keys(s.gali);
    if (m.gali.length !== orders.length) fail(`${s.name}: ${m.gali.length} GALI orders, report ${orders.length}`);
    m.gali.forEach((g, o) => mean(`${s.name} GALI_${o + 2}`, g, s.gali[String(o + 2)]));
    if (s.sali) mean(`${s.name} SALI`, m.sali, s.sali);
    same(`${s.name} mle`, m.mle, s.mle);
    if (s.orthonormalize === "qr") {
      if (m.spectrum.length !== s.lyapunov.length) fail(`${s.name}: spectrum length`);
      m.spectrum.forEach((l, i) => same(`${s.name} lambda_${i + 1}`, l, s.lyapunov[i]));
    }
    // Every registered set indicator by its report name (FLI, MEGNO, ...): the same doubles.
    // One the recorder cannot give (OFLI needs the system's vector field) says why instead.
    if (!m.named || !m.named.some((n) => n.name === "megno_mean")) fail(`${s.name}: no named indicators`);
    for (const n of m.named) {
      if (!(n.name in s)) fail(`${s.name}: ${n.name} not in the report`);
      if (n.unavailable) {
        if (n.mean !== undefined && n.mean !== null) fail(`${s.name} ${n.name}: a value and a reason`);
        continue;
      }
      same(`${s.name} ${n.name}.mean`, n.mean, s[n.name].mean);
      same(`${s.name} ${n.name}.std`, n.std, s[n.name].std);
    }
  }
}

main().catch((e) => fail(e?.stack ?? String(e)));

// Decode every message of an MCAP file the way Foxglove does, and print what came out.
//
//   node test/js/decode_bag.mjs FILE.mcap [--stream]
//
// Foxglove reads a ROS 2 MCAP with these very packages (@mcap/core, @foxglove/rosmsg,
// @foxglove/rosmsg2-serialization, @foxglove/wasm-zstd): for a channel with message encoding
// "cdr" and schema encoding "ros2msg", it parses the schema text with
// parse(text, { ros2: true }) and decodes each message with a MessageReader built from the
// parsed definitions. Indexed reading needs the file's summary (a finished recording);
// --stream reads the records in order instead, as Foxglove does for an unindexed file, and
// stops at a cut-off tail.
//
// Prints one JSON object: the header's profile, each schema that failed to parse with its
// error, and per topic the messages read, decoded, failed, and decoded with bytes left
// over beyond CDR's alignment padding (a schema that does not match the payload), plus a
// fingerprint of every decoded message (test/test_bag_readers.py compares it with the
// Python readers').
// Exit status 0 whenever the file could be read at all.

import { readFileSync } from "node:fs";
import { open } from "node:fs/promises";

import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import * as zstd from "@foxglove/wasm-zstd";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";

// Arrays longer than this are fingerprinted by length and a few sampled elements.
const FULL_ARRAY = 64;
const SAMPLES = 8;

/** A JSON-safe summary of a decoded value that the Python side can compute too. */
function fingerprint(value) {
  if (value === null || value === undefined) {
    return null;
  }
  if (typeof value === "bigint") {
    return Number.isSafeInteger(Number(value)) ? Number(value) : value.toString();
  }
  if (typeof value === "number") {
    if (Number.isNaN(value)) return "nan";
    if (value === Infinity) return "inf";
    if (value === -Infinity) return "-inf";
    return value;
  }
  if (typeof value === "string" || typeof value === "boolean") {
    return value;
  }
  if (ArrayBuffer.isView(value) || Array.isArray(value)) {
    const items = Array.from(value);
    if (items.length <= FULL_ARRAY) {
      return items.map(fingerprint);
    }
    const picks = [];
    for (let i = 0; i < SAMPLES; i++) {
      picks.push(fingerprint(items[Math.floor((i * (items.length - 1)) / (SAMPLES - 1))]));
    }
    return { len: items.length, samples: picks };
  }
  const out = {};
  for (const key of Object.keys(value).sort()) {
    out[key] = fingerprint(value[key]);
  }
  return out;
}

async function indexedMessages(path, decompressHandlers) {
  const handle = await open(path, "r");
  const readable = {
    size: async () => BigInt((await handle.stat()).size),
    read: async (offset, size) => {
      const buffer = new Uint8Array(Number(size));
      await handle.read(buffer, 0, Number(size), Number(offset));
      return buffer;
    },
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const messages = [];
  for await (const message of reader.readMessages()) {
    messages.push(message);
  }
  await handle.close();
  return { profile: reader.header.profile, channels: reader.channelsById,
    schemas: reader.schemasById, messages, complete: true };
}

function streamedMessages(path, decompressHandlers) {
  const reader = new McapStreamReader({ decompressHandlers });
  reader.append(readFileSync(path));
  const channels = new Map();
  const schemas = new Map();
  const messages = [];
  let profile;
  let error;
  for (;;) {
    let record;
    try {
      record = reader.nextRecord();
    } catch (err) {
      error = String(err); // a cut-off tail: keep what came before
      break;
    }
    if (record === undefined) break;
    if (record.type === "Header") profile = record.profile;
    else if (record.type === "Schema") schemas.set(record.id, record);
    else if (record.type === "Channel") channels.set(record.id, record);
    else if (record.type === "Message") messages.push(record);
  }
  return { profile, channels, schemas, messages, complete: reader.done(), error };
}

async function main() {
  const [path, ...flags] = process.argv.slice(2);
  if (!path) {
    console.error("usage: node decode_bag.mjs FILE.mcap [--stream]");
    process.exit(2);
  }
  await zstd.isLoaded;
  const decompressHandlers = {
    zstd: (data, size) => zstd.decompress(data, Number(size)),
  };
  const bag = flags.includes("--stream")
    ? streamedMessages(path, decompressHandlers)
    : await indexedMessages(path, decompressHandlers);

  const schemaErrors = {};
  const readers = new Map(); // channel id -> MessageReader, or undefined if it failed
  const topics = {};
  for (const [id, channel] of bag.channels) {
    topics[channel.topic] = { messages: 0, decoded: 0, failed: 0, trailing: 0,
      first_error: null, fingerprints: [] };
    const schema = bag.schemas.get(channel.schemaId);
    if (channel.messageEncoding !== "cdr" || schema?.encoding !== "ros2msg") {
      schemaErrors[schema?.name ?? channel.topic] =
        `unexpected encodings ${channel.messageEncoding}/${schema?.encoding}`;
      continue;
    }
    try {
      const text = new TextDecoder().decode(schema.data);
      readers.set(id, new MessageReader(parse(text, { ros2: true })));
    } catch (err) {
      schemaErrors[schema.name] = String(err);
    }
  }
  for (const message of bag.messages) {
    const channel = bag.channels.get(message.channelId);
    const entry = topics[channel.topic];
    entry.messages += 1;
    const reader = readers.get(message.channelId);
    if (reader === undefined) {
      entry.failed += 1;
      continue;
    }
    try {
      const decoded = reader.readMessage(message.data);
      entry.decoded += 1;
      // Fast DDS pads a payload that crosses processes to a multiple of 4 bytes with up to
      // 3 zero bytes; anything more is data the schema did not account for.
      const rest = message.data.subarray(reader.lastReadByteLength());
      if (rest.length > 3 || rest.some((b) => b !== 0)) entry.trailing += 1;
      entry.fingerprints.push(fingerprint(decoded));
    } catch (err) {
      entry.failed += 1;
      entry.first_error ??= String(err);
    }
  }
  process.stdout.write(JSON.stringify({
    profile: bag.profile, complete: bag.complete, stream_error: bag.error ?? null,
    schema_errors: schemaErrors, topics,
  }) + "\n");
}

main().catch((err) => {
  console.error(`decode_bag.mjs: ${err?.stack ?? err}`);
  process.exit(1);
});

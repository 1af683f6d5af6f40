// Connect to a Foxglove WebSocket server the way Foxglove does, subscribe to some topics,
// decode what arrives, and print what came out.
//
//   node test/js/foxglove_client.mjs ws://127.0.0.1:PORT TIMEOUT_S TOPIC...
//
// The client is Foxglove's own (@foxglove/ws-protocol's FoxgloveClient over the `ws`
// package). foxglove-sdk's server speaks the subprotocol "foxglove.sdk.v1" and refuses a
// client that offers only "foxglove.websocket.v1" (ws-protocol's default), so both are
// offered. For each topic, once the server advertises it, the
// client subscribes and decodes every message with the schema the server advertised:
// message encoding "cdr", schema encoding "ros2msg", parsed with parse(text, { ros2: true })
// and read with @foxglove/rosmsg2-serialization's MessageReader, as Foxglove decodes a
// ros2msg/cdr channel.
//
// Prints one JSON object once every topic is done (below), or at the timeout: the
// server's status messages, and per topic the advertised schema name and encodings, the
// messages received and decoded, the first decoding error, and a summary of what was
// decoded (TF frame ids, marker counts, image marker points, image geometry, string
// lengths). Exit status 0 when every topic is done, 1 at the timeout, 2 when the
// connection failed.

import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;
const [url, timeoutArg, ...topics] = process.argv.slice(2);
const timeoutMs = Number(timeoutArg) * 1000;

const out = { url, connected: false, advertised: [], status: [], topics: {} };
for (const topic of topics) {
  out.topics[topic] = { advertised: false, received: 0, decoded: 0, error: null };
}

/** What a test checks of one decoded message, by schema. */
function summarize(schemaName, msg, summary) {
  if (schemaName === "tf2_msgs/msg/TFMessage") {
    const frames = new Set(summary.frames ?? []);
    const children = new Set(summary.child_frames ?? []);
    for (const t of msg.transforms) {
      frames.add(t.header.frame_id);
      children.add(t.child_frame_id);
    }
    summary.frames = [...frames].sort();
    summary.child_frames = [...children].sort();
    summary.transforms = msg.transforms.length;
  } else if (schemaName === "visualization_msgs/msg/MarkerArray") {
    // The largest array so far (the first one of a run holds only its DELETEALL).
    if (msg.markers.length > (summary.markers ?? -1)) {
      summary.markers = msg.markers.length;
      summary.actions = msg.markers.map((m) => m.action);
      summary.namespaces = [...new Set(msg.markers.map((m) => m.ns))].sort();
      summary.frames = [...new Set(msg.markers.map((m) => m.header.frame_id))].sort();
    }
  } else if (schemaName === "visualization_msgs/msg/ImageMarker") {
    // The marker with the most points so far (a pair without ROIs has none).
    if (msg.points.length > (summary.points ?? -1)) {
      summary.points = msg.points.length;
      summary.outline_colors = msg.outline_colors.length;
      summary.type = msg.type;
      summary.action = msg.action;
      summary.scale = msg.scale;
      summary.frame_id = msg.header.frame_id;
      summary.max_u = Math.max(...msg.points.map((p) => p.x));
      summary.max_v = Math.max(...msg.points.map((p) => p.y));
    }
  } else if (schemaName === "sensor_msgs/msg/Image") {
    summary.width = msg.width;
    summary.height = msg.height;
    summary.encoding = msg.encoding;
    summary.step = msg.step;
    summary.data_bytes = msg.data.length;
    summary.frame_id = msg.header.frame_id;
  } else if (schemaName === "std_msgs/msg/String") {
    summary.length = msg.data.length;
    summary.head = msg.data.slice(0, 200);
  } else {
    summary.fields = Object.keys(msg).sort();
  }
}

/** A topic is done once it decoded a message; a marker array once it held a marker besides
 * the DELETEALL that starts each of Roger's; an image marker once it drew something. */
function done() {
  return topics.every((t) => {
    const entry = out.topics[t];
    if (entry.schema_name === "visualization_msgs/msg/MarkerArray") {
      return (entry.summary?.markers ?? 0) > 1;
    }
    if (entry.schema_name === "visualization_msgs/msg/ImageMarker") {
      return (entry.summary?.points ?? 0) > 0;
    }
    return entry.decoded > 0;
  });
}

let client;
let finished = false;
function finish(code) {
  if (finished) return;
  finished = true;
  process.stdout.write(JSON.stringify(out) + "\n");
  try {
    client?.close();
  } catch {
    // already closed
  }
  process.exit(code);
}

setTimeout(() => finish(1), timeoutMs);
client = new FoxgloveClient({
  ws: new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]),
});
const subscriptions = new Map(); // subscription id -> { topic, schemaName, reader }

client.on("open", () => {
  out.connected = true;
});
// The server's complaints (a refused subscription: "Unknown channel ID").
client.on("status", (status) => {
  out.status.push(status.message);
});
client.on("error", (error) => {
  out.connection_error = String(error?.message ?? error);
  if (!out.connected) finish(2);
});
client.on("close", () => {
  if (!finished) {
    out.closed_by_server = true;
    finish(done() ? 0 : 1);
  }
});
client.on("advertise", (channels) => {
  for (const channel of channels) {
    out.advertised.push(channel.topic);
    const entry = out.topics[channel.topic];
    if (entry === undefined || entry.advertised) continue;
    entry.advertised = true;
    entry.schema_name = channel.schemaName;
    entry.encoding = channel.encoding;
    entry.schema_encoding = channel.schemaEncoding;
    let reader;
    try {
      reader = new MessageReader(parse(channel.schema, { ros2: true }));
    } catch (error) {
      entry.error = `schema: ${error.message}`;
      continue;
    }
    entry.summary = {};
    const id = client.subscribe(channel.id);
    subscriptions.set(id, { topic: channel.topic, schemaName: channel.schemaName, reader });
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const sub = subscriptions.get(subscriptionId);
  if (sub === undefined) return;
  const entry = out.topics[sub.topic];
  entry.received += 1;
  try {
    const msg = sub.reader.readMessage(
      new Uint8Array(data.buffer, data.byteOffset, data.byteLength),
    );
    summarize(sub.schemaName, msg, entry.summary);
    entry.decoded += 1;
  } catch (error) {
    entry.error ??= `decode: ${error.message}`;
  }
  if (done()) finish(0);
});

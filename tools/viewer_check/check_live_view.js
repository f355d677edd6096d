// Runs a real Foxglove-family viewer's own code over what the live view serves: the open-source Foxglove Studio's
// published bundle (@foxglove/studio-base 1.48.0, pinned in package-lock.json). Nothing here parses a schema or a
// message path itself: the viewer's parseChannel (mcap-support, the function its WebSocket player calls on every
// advertised channel), parseRosPath and traverseStructure (its message-path syntax, as the Plot panel's path input
// validates a path) do.
//
// stdin: {"channels": [advertised channel objects, as the server sent them],
//         "messages": {topic: [base64 payloads of received messages]},
//         "layout": the layout JSON}
// stdout: one JSON report {"channels": {topic: {"ok", "error", "datatypes"}}, "paths": [{"panel", "path", "ok",
//         "error", "value"}]}; exit 0 when every channel parses, every message given decodes, and every path of the
//         layout resolves in the parsed definitions and holds data (a finite number for a plot) in a decoded message.
"use strict";

const fs = require("fs");
const path = require("path");

const BUNDLE = path.join(__dirname, "node_modules", "@foxglove", "studio-base", "assets", "index.js");
const ENTRY = "var __webpack_exports__ = {};";
const MCAP_SUPPORT = ["// EXTERNAL MODULE: ../../node_modules/@protobufjs/base64/index.js",
  ";// CONCATENATED MODULE: ../mcap-support/src/index.ts"];
const PARSE_ROS_PATH = 40445; // webpack module ./src/components/MessagePathSyntax/parseRosPath.ts
const MESSAGE_PATHS = 92877; // webpack module ./src/components/MessagePathSyntax/messagePathsForDatatype.ts
const NUMERIC = ["int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64"];

/** The viewer's functions, taken from its bundle: its webpack runtime and modules without running the app. */
function loadViewer() {
  const bundle = fs.readFileSync(BUNDLE); // 56 MB: searched as bytes, only the parts used are decoded
  const start = bundle.indexOf("var __webpack_modules__ = ({");
  const entry = bundle.indexOf(ENTRY, start);
  const [from, to] = MCAP_SUPPORT.map((marker) => bundle.indexOf(marker, entry));
  if (start < 0 || entry < 0 || from < 0 || to < 0) {
    throw new Error(`${BUNDLE}: not the bundle this script knows (webpack runtime or mcap-support not found)`);
  }
  // the runtime of the UMD bundle, returning its require instead of running the app's entry module
  const runtime = new Function("__WEBPACK_EXTERNAL_MODULE__8156__", "__WEBPACK_EXTERNAL_MODULE__47111__", "self",
    `${bundle.toString("utf8", start, entry)}\nreturn __webpack_require__;`);
  const page = { location: { href: "file:///studio-base/index.js" } };
  globalThis.document = { currentScript: { src: page.location.href }, baseURI: page.location.href };
  let require;
  try {
    require = runtime({}, {}, page); // react and react-dom: not used by the modules taken here
  } finally {
    delete globalThis.document;
  }
  // mcap-support is concatenated into the entry module: its section, evaluated with the bundle's require
  const mcap = new Function("__webpack_require__",
    `${bundle.toString("utf8", from, to)}\nreturn { parseChannel };`)(require);
  const messagePaths = require(MESSAGE_PATHS);
  return {
    parseChannel: mcap.parseChannel,
    parseRosPath: require(PARSE_ROS_PATH).ZP,
    messagePathStructures: messagePaths.pb,
    traverseStructure: messagePaths.eT,
    validTerminatingStructureItem: messagePaths.Ky,
  };
}

/** The channel as the viewer's FoxgloveWebSocketPlayer hands it to parseChannel (schema bytes by encoding). */
function playerChannel(channel) {
  const json = channel.encoding === "json";
  return {
    messageEncoding: channel.encoding,
    schema: {
      name: channel.schemaName,
      encoding: json ? "jsonschema" : channel.encoding,
      data: json ? new TextEncoder().encode(channel.schema) : Buffer.from(channel.schema, "base64"),
    },
  };
}

/** The layout's message paths by panel, with the types a panel can show at the end of each. */
function layoutPaths(layout) {
  const paths = [];
  for (const [panel, config] of Object.entries(layout.configById)) {
    const kind = panel.split("!")[0];
    for (const p of config.paths ?? []) {
      paths.push({ panel, path: p.value, validTypes: NUMERIC });
    }
    if (config.topicPath) {
      paths.push({ panel, path: config.topicPath, validTypes: kind === "Table" ? ["array"] : undefined });
    }
    for (const topic of Object.keys(config.topics ?? {})) {
      paths.push({ panel, path: topic, validTypes: undefined });
    }
  }
  return paths;
}

/** The value at a parsed message path in a decoded message (names and single indices, as the layout uses). */
function valueAt(message, messagePath) {
  let value = message;
  for (const part of messagePath) {
    if (value == undefined) {
      return undefined;
    }
    if (part.type === "name") {
      value = value[part.name];
    } else if (part.type === "slice" && part.start === part.end && typeof part.start === "number") {
      value = value[part.start];
    } else {
      throw new Error(`path part ${JSON.stringify(part)} not handled by this check`);
    }
  }
  return value;
}

function main() {
  const input = JSON.parse(fs.readFileSync(0, "utf8"));
  const viewer = loadViewer();
  const report = { channels: {}, paths: [] };
  const parsed = {};
  for (const channel of input.channels) {
    try {
      const result = viewer.parseChannel(playerChannel(channel));
      parsed[channel.topic] = { channel, result };
      report.channels[channel.topic] = { ok: true, datatypes: [...result.datatypes.keys()] };
    } catch (error) {
      report.channels[channel.topic] = { ok: false, error: `Failed to parse channel schema: ${error.message}` };
    }
  }
  for (const { panel, path: text, validTypes } of layoutPaths(input.layout)) {
    const entry = { panel, path: text, ok: false };
    report.paths.push(entry);
    const rosPath = viewer.parseRosPath(text);
    if (!rosPath) {
      entry.error = "the viewer cannot parse this message path";
      continue;
    }
    const topic = parsed[rosPath.topicName];
    if (!topic) {
      entry.error = `no parsed channel ${rosPath.topicName}`;
      continue;
    }
    const structure = viewer.messagePathStructures(topic.result.datatypes)[topic.channel.schemaName];
    const { valid, structureItem } = viewer.traverseStructure(structure, rosPath.messagePath);
    if (!valid || !viewer.validTerminatingStructureItem(structureItem, validTypes)) {
      entry.error = `path does not resolve in the parsed definitions (${JSON.stringify(structureItem)})`;
      continue;
    }
    const shows = (value) => (validTypes === NUMERIC ? typeof value === "number" && Number.isFinite(value)
      : value != undefined);
    const values = (input.messages[rosPath.topicName] ?? []).map((payload) =>
      valueAt(topic.result.deserialize(Buffer.from(payload, "base64")), rosPath.messagePath));
    if (values.length === 0) {
      entry.error = "no message received on this topic";
      continue;
    }
    const value = values.findLast(shows);
    const shown = value !== undefined;
    entry.value = value === undefined || typeof value === "number" || typeof value === "string" ? value
      : Array.isArray(value) ? `array of ${value.length}` : typeof value;
    entry.ok = shown;
    if (!shown) {
      entry.error = `no data at this path in the ${values.length} decoded messages`;
    }
  }
  process.stdout.write(`${JSON.stringify(report)}\n`);
  const ok = Object.values(report.channels).every((c) => c.ok) && report.paths.every((p) => p.ok);
  process.exitCode = ok ? 0 : 1;
}

main();

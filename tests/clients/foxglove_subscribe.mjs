// Foxglove's own websocket client (@foxglove/ws-protocol) against the ground's live view:
//   node foxglove_subscribe.mjs URL TOKEN
// offers only the protocol's first name (FoxgloveClient.SUPPORTED_SUBPROTOCOL,
// "foxglove.websocket.v1"), sends the token as Authorization: Bearer, subscribes to every
// channel as it is advertised and prints one JSON line {"event": "subscribed", ...} once
// the first advertisement is taken; when standard input closes (having given the number
// of /tf messages to wait for) it prints
// {"event": "done", "subprotocol", "channels": {topic: schemaName}, "counts": {topic: n},
//  "first": {topic: [log time ns, payload bytes]}} and exits 0. Any error: exit 1 with it
// on standard error.
import wsProtocol from "@foxglove/ws-protocol"; // CommonJS: its exports come as one object
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;
const [url, token] = process.argv.slice(2);
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL], {
  headers: { Authorization: `Bearer ${token}` },
});
const client = new FoxgloveClient({ ws });
const channels = {};
const counts = {};
const first = {};
const topics = new Map(); // subscription id -> topic
let announced = false;

function fail(error) {
  process.stderr.write(`foxglove client: ${error}\n`);
  process.exit(1);
}

ws.on("unexpected-response", (_request, response) => {
  fail(`handshake refused: HTTP ${response.statusCode}`);
});
client.on("error", (error) => fail(error?.message ?? String(error)));
client.on("advertise", (advertised) => {
  for (const channel of advertised) {
    channels[channel.topic] = channel.schemaName;
    counts[channel.topic] ??= 0;
    topics.set(client.subscribe(channel.id), channel.topic);
  }
  if (!announced) {
    announced = true;
    console.log(JSON.stringify({ event: "subscribed", subprotocol: ws.protocol }));
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const topic = topics.get(subscriptionId);
  counts[topic] += 1;
  first[topic] ??= [timestamp.toString(), data.byteLength];
});
// Standard input: the number of /tf messages the test knows were sent; once that many came
// (or 60 s passed: a guard, the test then sees the short count), print and exit.
let input = "";
process.stdin.setEncoding("utf8");
process.stdin.on("data", (chunk) => {
  input += chunk;
});
process.stdin.on("end", () => {
  const wanted = Number.parseInt(input.trim() || "0", 10);
  const deadline = Date.now() + 60_000;
  const timer = setInterval(() => {
    if ((counts["/tf"] ?? 0) < wanted && Date.now() < deadline) {
      return;
    }
    clearInterval(timer);
    const done = { event: "done", subprotocol: ws.protocol, channels, counts, first };
    console.log(JSON.stringify(done));
    client.close();
    process.exit(0);
  }, 50);
});
process.stdin.resume();

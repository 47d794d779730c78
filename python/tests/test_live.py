"""The live view (`train --live`), watched by a client written from Foxglove's WebSocket protocol
specification (foxglove/ws-protocol, `foxglove.sdk.v1`) with nothing but `websockets`: it
reads the server's channel advertisements, subscribes, and decodes the binary message frames
(opcode 1, subscription id, log time, payload). While cart-pole trains, arena 0's joint states
arrive every control step (their stamps, the simulated time, one control period apart), the
transforms name every link of the arenas, the scene arrives on subscribing, and a malformed
request gets a status reply while the server keeps serving."""

import asyncio
import json
import os
import shutil
import struct
import subprocess
from pathlib import Path

import pytest

websockets = pytest.importorskip("websockets")

REPO = Path(__file__).resolve().parents[2]


def twinbots_bin():
    binary = os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")
    if not binary:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN)")
    return binary


async def watch(port, topics, seconds):
    """Subscribes to `topics` and returns, per topic, the (log time, payload) of every message
    received within `seconds`, and the status messages the server sent."""
    url = f"ws://127.0.0.1:{port}"
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=1 << 28) as ws:
        assert ws.subprotocol == "foxglove.sdk.v1"
        channels, statuses = {}, []
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 30
        while not all(t in channels for t in topics):
            assert loop.time() < deadline, f"never advertised: {set(topics) - set(channels)}"
            frame = await asyncio.wait_for(ws.recv(), 30)
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "advertise":
                    channels.update({c["topic"]: c for c in message["channels"]})
        subscriptions = [{"id": k + 1, "channelId": channels[t]["id"]} for k, t in enumerate(topics)]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        # A request the protocol does not have: the server answers with a status and serves on.
        await ws.send(json.dumps({"op": "no-such-op"}))
        await ws.send("{not json")
        received = {t: [] for t in topics}
        end = loop.time() + seconds
        while loop.time() < end:
            try:
                frame = await asyncio.wait_for(ws.recv(), end - loop.time())
            except asyncio.TimeoutError:
                break
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "status":
                    statuses.append(message)
                continue
            assert frame[0] == 0x01, f"opcode {frame[0]}"
            subscription, log_time = struct.unpack_from("<IQ", frame, 1)
            received[topics[subscription - 1]].append((log_time, frame[13:]))
        return channels, received, statuses


def test_a_foxglove_client_watches_cartpole_train(tmp_path):
    binary = twinbots_bin()
    listing = subprocess.run([binary, "robots", "--json"], capture_output=True, text=True, check=True).stdout
    robots = json.loads(listing)["robots"]
    control_period = next(r for r in robots if r["name"] == "cartpole")["tasks"][0]["control_period_s"]
    command = [
        binary,
        "train",
        "cartpole",
        "--live",
        "127.0.0.1:0",
        "--timesteps",
        "5000000",
        "--out",
        str(tmp_path / "run"),
    ]
    train = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        first = train.stdout.readline()
        assert first.startswith("live view on ws://127.0.0.1:"), first + train.stderr.read()
        port = int(first.split(":")[2].split()[0])
        topics = ["/arena_0/joint_states", "/tf", "/scene"]
        channels, received, statuses = asyncio.run(watch(port, topics, 4.0))
        assert train.poll() is None, "training stopped while watched"
    finally:
        train.kill()
        train.wait()

    assert channels["/arena_0/joint_states"]["schemaName"] == "sensor_msgs/JointState"
    assert channels["/tf"]["schemaName"] == "foxglove.FrameTransforms"
    assert channels["/tf"]["encoding"] == "protobuf"
    # Every control step: the stamps (simulated time) one control period apart.
    states = [json.loads(payload) for _, payload in received["/arena_0/joint_states"]]
    assert len(states) >= 100, len(states)
    assert states[0]["name"] and len(states[0]["position"]) == len(states[0]["name"])
    stamps = [s["header"]["stamp"]["sec"] + 1e-9 * s["header"]["stamp"]["nsec"] for s in states]
    steps = [round((b - a) / control_period, 6) for a, b in zip(stamps, stamps[1:])]
    in_step = sum(1 for s in steps if s == 1.0) / len(steps)
    assert in_step >= 0.9, f"only {in_step:.0%} of consecutive joint states one control step apart: {steps[:20]}"
    # The transforms: every arena's frame and its links', as many messages as joint states.
    transforms = received["/tf"]
    assert len(transforms) >= 0.5 * len(states), (len(transforms), len(states))
    payload = transforms[-1][1]
    assert b"arena_0" in payload and b"arena_0/pole" in payload, payload[:200]
    # The scene, on subscribing: each link's visuals in its frame.
    assert received["/scene"], "no scene"
    assert b"arena_0/pole" in received["/scene"][0][1]
    # Both malformed requests answered with a status (error level 2), none ended the session.
    assert len([s for s in statuses if s.get("level") == 2]) >= 2, statuses
    # The layout that ships for Foxglove and Lichtblick names topics the live view serves.
    layout = json.loads((REPO / "assets/foxglove/twinbots.json").read_text())
    named = set()
    for config in layout["configById"].values():
        named.update(config.get("topics", {}))
        named.update([config["topicPath"]] if "topicPath" in config else [])
        named.update(path["value"].split(".")[0] for path in config.get("paths", []))
    assert named and named <= set(channels), named - set(channels)
    panels = json.dumps(layout["layout"])
    assert all(panel in panels for panel in layout["configById"]), "a configured panel is not in the layout"


def test_a_foxglove_client_watches_an_evaluation(tmp_path):
    """`eval --live`: the evaluation's arenas and the episodes as they end."""
    binary = twinbots_bin()
    run = tmp_path / "run"
    subprocess.run(
        [binary, "train", "cartpole", "--timesteps", "2048", "--out", str(run)],
        capture_output=True, check=True, cwd=REPO,
    )
    command = [binary, "eval", str(run), "--episodes", "1000000", "--live", "127.0.0.1:0"]
    evaluation = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        first = evaluation.stdout.readline()
        assert first.startswith("live view on ws://127.0.0.1:"), first + evaluation.stderr.read()
        port = int(first.split(":")[2].split()[0])
        channels, received, _ = asyncio.run(watch(port, ["/arena_0/joint_states", "/episodes"], 3.0))
        assert evaluation.poll() is None, "the evaluation stopped while watched"
    finally:
        evaluation.kill()
        evaluation.wait()
    assert channels["/episodes"]["schemaName"] == "twinbots/Episode"
    assert len(received["/arena_0/joint_states"]) >= 100, len(received["/arena_0/joint_states"])
    episodes = [json.loads(payload) for _, payload in received["/episodes"]]
    assert episodes and all(e["length"] >= 1 for e in episodes), episodes[:3]

"""A bridge client in its own process (roslibpy runs a Twisted reactor that cannot restart in-process).

usage: python bridge_probe.py roslibpy|ours PORT [TOKEN]
Subscribes `prompt_text`, publishes `response_text` ("<lib> says hi") every 50 ms, prints each
received message as `RECV <json>` and exits after the first one (or after 20 s).
"""

from __future__ import annotations

import asyncio
import json
import sys
import threading
import time


def run_roslibpy(port: int, token: str) -> None:
    import roslibpy

    headers = {"Authorization": f"Bearer {token}"} if token else None
    ros = roslibpy.Ros("127.0.0.1", port, headers=headers)
    ros.run(timeout=10)
    received = threading.Event()

    def on_message(message: dict[str, object]) -> None:
        print("RECV " + json.dumps(message), flush=True)
        received.set()

    roslibpy.Topic(ros, "prompt_text", "std_msgs/String").subscribe(on_message)
    publisher = roslibpy.Topic(ros, "response_text", "std_msgs/String")
    print("ready", flush=True)
    deadline = time.monotonic() + 20
    while not received.is_set() and time.monotonic() < deadline:
        publisher.publish(roslibpy.Message({"data": "roslibpy says hi"}))
        received.wait(0.05)
    ros.terminate()


async def run_ours(port: int, token: str) -> None:
    from by_your_command.bridge.client import BridgeClient, ClientOptions

    async with BridgeClient(f"ws://127.0.0.1:{port}/", ClientOptions(token=token)) as client:
        await client.wait_connected(10)
        await client.subscribe("prompt_text", "std_msgs/msg/String")
        await client.advertise("response_text", "std_msgs/msg/String")
        print("ready", flush=True)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            await client.publish("response_text", {"data": "ours says hi"})
            try:
                incoming = await client.receive(0.05)
            except TimeoutError:
                continue
            print("RECV " + json.dumps(incoming.msg), flush=True)
            return


def main() -> None:
    lib, port = sys.argv[1], int(sys.argv[2])
    token = sys.argv[3] if len(sys.argv) > 3 else ""
    if lib == "roslibpy":
        run_roslibpy(port, token)
    else:
        asyncio.run(run_ours(port, token))


if __name__ == "__main__":
    main()

"""Two users walk down a street of pvsd's built-in city together over
WebSockets, each holding its visible set from deltas.

    pip install websockets
    pvsd serve &            # the built-in city, on 127.0.0.1:8080
    python3 examples/ws_walk.py [http://127.0.0.1:8080] [method]
"""
import asyncio
import json
import sys
import urllib.request

import websockets

METHOD = sys.argv[2] if len(sys.argv) > 2 else "horizon"
BASE = sys.argv[1] if len(sys.argv) > 1 else "http://127.0.0.1:8080"


def post(path, body=None):
    req = urllib.request.Request(BASE + path, data=json.dumps(body or {}).encode(), method="POST")
    with urllib.request.urlopen(req) as r:
        return json.load(r)


async def walk(name, session, start, step, frames):
    url = BASE.replace("http", "ws", 1) + f"/sessions/{session}/ws"
    held = set()
    async with websockets.connect(url) as ws:
        for i in range(frames):
            eye = [start[0] + step * i, 1.7, start[1] + 0.27 * step * i]
            await ws.send(json.dumps({"eye": eye, "forward": [step, 0, 0.27 * step]}))
            f = json.loads(await ws.recv())
            if "error" in f:
                raise SystemExit(f"{name}: {f['error']}")
            if f["base"] is None:
                held.clear()
            held -= set(f["removed"])
            held |= set(f["added"])
            print(f"{name} frame {f['frame']}: +{len(f['added'])} -{len(f['removed'])} "
                  f"holds {len(held)}, sees users {f['users_visible']}")
            await asyncio.sleep(0.05)


async def main():
    wid = post("/walkthroughs", {"scene": "city", "method": METHOD})["walkthrough"]
    alice, bob = post(f"/walkthroughs/{wid}/users"), post(f"/walkthroughs/{wid}/users")
    print("alice is", alice["user"], "- bob is", bob["user"])
    # They walk towards each other along a street (the city is turned 15°).
    await asyncio.gather(
        walk("alice", alice["session"], (400, 150), 1, 5),
        walk("bob", bob["session"], (420, 155.4), -1, 5),
    )


asyncio.run(main())

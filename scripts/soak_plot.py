#!/usr/bin/env python3
"""Plots a soak's samples (docs/soak.csv: seconds, rss_kib, fds) as an SVG
with no dependencies, and prints the summary the README quotes: RSS after
warm-up (2 min) and its spread, open files, the run's frames and errors.

    scripts/soak_plot.py docs/soak.csv docs/soak.json docs/soak.svg
"""
import csv
import json
import sys

WARM_UP_S = 120

rows = [(float(r["seconds"]), int(r["rss_kib"]) / 1024, int(r["fds"]))
        for r in csv.DictReader(open(sys.argv[1]))]
report = json.load(open(sys.argv[2]))
after = [r for r in rows if r[0] >= WARM_UP_S] or rows
rss = [r[1] for r in after]
base = rss[0]
spread = (max(rss) - min(rss)) / base
fds = [r[2] for r in rows]
summary = (f"{report['requests']} frames in {report['seconds'] / 60:.0f} min "
           f"({report['rps']:.0f}/s), errors {report['errors']}, p99 {report['p99_ms']:.2f} ms, "
           f"sessions churned {report.get('churned', 0)}; RSS after warm-up "
           f"{min(rss):.1f}–{max(rss):.1f} MiB (spread {spread:.1%} of {base:.1f}), "
           f"open files {min(fds)}–{max(fds)}")
print(summary)

W, H, L, B = 720, 300, 60, 40
t_max = max(r[0] for r in rows) or 1
r_max = max(r[1] for r in rows) * 1.15
f_max = max(fds) * 1.15 or 1


def x(t):
    return L + (W - L - 60) * t / t_max


def y(v, top):
    return H - B - (H - B - 20) * v / top


def line(points, colour):
    pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in points)
    return f'<polyline fill="none" stroke="{colour}" stroke-width="1.5" points="{pts}"/>'


svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="11">',
       f'<rect width="{W}" height="{H}" fill="white"/>',
       f'<line x1="{L}" y1="{H - B}" x2="{W - 60}" y2="{H - B}" stroke="black"/>',
       f'<line x1="{L}" y1="20" x2="{L}" y2="{H - B}" stroke="black"/>',
       f'<line x1="{W - 60}" y1="20" x2="{W - 60}" y2="{H - B}" stroke="black"/>']
for i in range(6):
    t = t_max * i / 5
    svg.append(f'<text x="{x(t):.0f}" y="{H - B + 15}" text-anchor="middle">{t / 60:.0f} min</text>')
    svg.append(f'<text x="{L - 5}" y="{y(r_max * i / 5, r_max):.0f}" text-anchor="end">{r_max * i / 5:.0f}</text>')
    svg.append(f'<text x="{W - 55}" y="{y(f_max * i / 5, f_max):.0f}">{f_max * i / 5:.0f}</text>')
svg.append(f'<line x1="{x(WARM_UP_S):.1f}" y1="20" x2="{x(WARM_UP_S):.1f}" y2="{H - B}" stroke="#bbb" stroke-dasharray="4"/>')
svg.append(line([(x(t), y(r, r_max)) for t, r, _ in rows], "#1f77b4"))
svg.append(line([(x(t), y(f, f_max)) for t, _, f in rows], "#d62728"))
svg.append(f'<text x="{L}" y="12" fill="#1f77b4">resident memory, MiB (left)</text>')
svg.append(f'<text x="{W - 60}" y="12" fill="#d62728" text-anchor="end">open files (right)</text>')
svg.append(f'<text x="{W / 2}" y="{H - 5}" text-anchor="middle">{summary[:110]}</text>')
svg.append("</svg>")
open(sys.argv[3], "w").write("\n".join(svg) + "\n")

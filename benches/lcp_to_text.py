#!/usr/bin/python3
"""Writes an LCP file of `ecp lcp` ({"M": [[..], ..], "q": [..]}) as the plain text that
benches/siconos_lemke.c reads: n, then M by rows, then q, in round-trip precision.

    python3 benches/lcp_to_text.py target/lcp/lcp_n10.json > target/lcp/lcp_n10.txt
"""

import json
import sys


def main():
    with open(sys.argv[1]) as f:
        data = json.load(f)
    print(len(data["q"]))
    for row in data["M"]:
        print(" ".join(repr(float(x)) for x in row))
    print(" ".join(repr(float(x)) for x in data["q"]))


if __name__ == "__main__":
    main()

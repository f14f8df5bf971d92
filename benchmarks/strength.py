"""How SIP's and HIG's lead over Adam changes with a nonlinear scene's strength (the seeds' claim), in
two protocols, each cell a plain ``pdeinv train`` run:

    OMP_NUM_THREADS=1 python benchmarks/strength.py sine_gordon_1d --strengths 0,30,100,300
        [--methods sip,hig,adam] [--noise 0] [--protocols defaults,rules] [--out runs/strength]

* ``defaults``: ``pdeinv train SCENE --method M --set strength=s`` as a user runs it: the rule trains
  the default network, then its correction is fitted on prior draws (``pdeinv.nets.refine``);
* ``rules``: the same with ``--prior-fit 0``, the network the rule trained and nothing else: the
  seeds' protocol (observations only, one network for every rule).

Prints the held-out x-error of every method and SIP / Adam, HIG / Adam per strength and protocol, and
writes ``OUT/strength.json``. One thread per run; run it alone (the prior fit's budget is CPU seconds,
so a loaded machine changes wall times, not the work).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from accuracy import train

PROTOCOLS = {"defaults": (), "rules": ("--prior-fit", "0")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--strengths", default="0,30,100,300")
    ap.add_argument("--methods", default="sip,hig,adam")
    ap.add_argument("--noise", type=float, default=0.0)
    ap.add_argument("--protocols", default="defaults,rules")
    ap.add_argument("--out", default="runs/strength")
    args = ap.parse_args(argv)
    protocols = args.protocols.split(",")
    unknown = sorted(set(protocols) - set(PROTOCOLS))
    if unknown:
        ap.error(f"--protocols {','.join(unknown)} is not allowed; expected some of {', '.join(PROTOCOLS)}")
    methods, rows = args.methods.split(","), []
    print(f"| protocol | strength | {' | '.join(methods)} | SIP / Adam | HIG / Adam |\n|"
          + "---|" * (len(methods) + 4), flush=True)
    for protocol in protocols:
        for s in args.strengths.split(","):
            extra = ("--set", f"strength={s}", *PROTOCOLS[protocol])
            row = {"protocol": protocol, "strength": float(s)}
            for m in methods:
                out = Path(args.out) / f"{args.scene}-{protocol}-{s}-{m}"
                row[m] = train(args.scene, m, args.noise, out, extra).get("x_err")
            rows.append(row)
            ratio = {k: (row[k] / row["adam"] if row.get(k) is not None and row.get("adam") else None)
                     for k in ("sip", "hig")}
            cells = [f"{row[m]:.3g}" if row[m] is not None else "failed" for m in methods]
            cells += [f"{ratio[k]:.2f}" if ratio[k] is not None else "—" for k in ("sip", "hig")]
            print(f"| {protocol} | {s} | {' | '.join(cells)} |", flush=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "strength.json").write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

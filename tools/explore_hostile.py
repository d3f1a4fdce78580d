"""Exploration of hostile diagrams (not a test; its findings are files of tests/hostile/).

    python tools/explore_hostile.py OUT.jsonl [FILE ...]    # FILE: diagrams/servo.yaml, ...
    python tools/explore_hostile.py --summary OUT.jsonl     # flagged mutants by kind and key

Every key and value of every shipped diagram (``diagrams/``, ``spider.yaml``, the library
subsystem ``diagrams/lib/lag.yaml``) is replaced in turn by a hostile value (booleans, null,
lists, mappings, NaN/inf texts and floats, huge and negative numbers, Unicode with invisible
and bidi characters, a 20,000-character text, 60-deep nesting) and every mapping key renamed
(an int, a boolean, null, Unicode, 5,000 characters); text-level mutants add duplicate
sections, an alias bomb, 5,000-deep flow nesting, a 300-deep block mapping, a BOM, CRLF line
ends and a truncated file. At most FUZZ_CAP (default 350) value/key mutants per file, drawn
with a fixed seed. Each mutant is written over its file in a copy of the tree (a subsystem
is checked through a parent that uses it) and run through ``spidersim check`` (in-process)
and ``spidersim.load``; one JSON line per mutant records the exit status, the time, the
API's exception type and the end of stderr. Flag: exit status other than 0/2, "internal
error", an exception other than SpidersimError from ``load``, more than 10 s, or exit 0 on a
value whose type differs from the original's (to be reviewed: many are valid).
"""
import contextlib, copy, io, json, os, random, shutil, signal, sys, tempfile, time
import yaml

SRC = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TREE = os.path.join(tempfile.gettempdir(), "spidersim_explore_tree")
sys.setrecursionlimit(3000)
from spidersim import cli
import spidersim
from spidersim.errors import SpidersimError

class Timeout(Exception):
    pass

def _alarm(*a):
    raise Timeout()
signal.signal(signal.SIGALRM, _alarm)

def deep(n, kind):
    v = 1
    for _ in range(n):
        v = [v] if kind == "list" else {"a": v}
    return v

HOSTILE = [("bool", True), ("bool", False), ("null", None), ("list", [1]), ("list", []),
           ("list", ["x", [2]]), ("dict", {}), ("dict", {"a": 1}), ("str", "x"), ("str", ""),
           ("nanstr", "nan"), ("infstr", "inf"), ("nanstr", ".nan"), ("float", float("nan")),
           ("float", float("inf")), ("float", -float("inf")), ("huge", 10 ** 30),
           ("huge", 2 ** 64), ("neg", -1), ("neg", -10 ** 9), ("zero", 0), ("float", 1e-320),
           ("unicode", "é☃\u200b\u202e"), ("long", "a" * 20000), ("deep", deep(60, "list")),
           ("deep", deep(60, "dict")), ("int", 7), ("float", 0.5)]
if os.environ.get("FUZZ_QUICK"):
    HOSTILE = HOSTILE[::2]

def paths(node, pre=()):
    yield pre
    if isinstance(node, dict):
        for k, v in node.items():
            yield from paths(v, pre + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from paths(v, pre + (i,))

def get(node, p):
    for k in p:
        node = node[k]
    return node

def put(node, p, v):
    node = copy.deepcopy(node)
    if not p:
        return v
    get(node, p[:-1])[p[-1]] = v
    return node

def rekey(node, p, newkey):
    node = copy.deepcopy(node)
    parent = get(node, p[:-1])
    if not isinstance(parent, dict):
        return None
    items = list(parent.items())
    parent.clear()
    for k, v in items:
        parent[newkey if k == p[-1] else k] = v
    return node

def kind_of(v):
    if isinstance(v, bool): return "bool"
    if isinstance(v, (int, float)): return "num"
    if isinstance(v, str): return "str"
    if isinstance(v, list): return "list"
    if isinstance(v, dict): return "dict"
    return "null"

def dump(data):
    text = yaml.safe_dump(data, allow_unicode=True, sort_keys=False, width=10 ** 9)
    return text

def run_one(text, target, parent):
    """write text at target (in TREE), check parent; return record"""
    with open(target, "w", encoding="utf-8") as fh:
        fh.write(text)
    err = io.StringIO()
    t0 = time.time()
    signal.alarm(10)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = cli.main(["check", parent])
    except Timeout:
        code = "timeout"
    except BaseException as exc:
        code = f"escaped {type(exc).__name__}"
    finally:
        signal.alarm(0)
    dt = time.time() - t0
    api = None
    signal.alarm(10)
    try:
        spidersim.load(parent)
        api = "ok"
    except SpidersimError:
        api = "err"
    except Timeout:
        api = "timeout"
    except BaseException as exc:
        api = f"{type(exc).__name__}: {str(exc)[:150]}"
    finally:
        signal.alarm(0)
    return code, err.getvalue(), dt, api

def main():
    if os.path.exists(TREE):
        shutil.rmtree(TREE)
    os.makedirs(TREE)
    shutil.copytree(os.path.join(SRC, "diagrams"), os.path.join(TREE, "diagrams"))
    shutil.copy(os.path.join(SRC, "spider.yaml"), TREE)
    out_path = os.path.abspath(sys.argv[1])
    only = sys.argv[2:]
    os.chdir(TREE)
    bases = sorted(os.path.join("diagrams", f) for f in os.listdir("diagrams")
                   if f.endswith(".yaml")) + ["spider.yaml", "diagrams/lib/lag.yaml"]
    parent_of = {"diagrams/joint.yaml": "diagrams/joint_step.yaml",
                 "diagrams/joint_torque.yaml": "diagrams/force_control_rigid.yaml",
                 "diagrams/lib/lag.yaml": "diagrams/three_lags.yaml"}
    out = open(out_path, "w")
    n = 0
    for base in bases:
        if only and base not in only:
            continue
        orig_text = open(base, encoding="utf-8").read()
        data = yaml.safe_load(orig_text)
        parent = parent_of.get(base, base)
        muts = []
        for p in paths(data):
            if not p:
                continue
            ov = get(data, p)
            for kind, v in HOSTILE:
                muts.append((p, "value", kind, kind_of(ov), put(data, p, v)))
            if isinstance(p[-1], str):
                for kind, nk in (("key_int", 5), ("key_unicode", "ké\u200b"), ("key_long", "k" * 5000),
                                 ("key_bool", True), ("key_null", None)):
                    m = rekey(data, p, nk)
                    if m is not None:
                        muts.append((p, "key", kind, "key", m))
        cap = int(os.environ.get("FUZZ_CAP", "350"))
        if len(muts) > cap:
            muts = random.Random(base).sample(muts, cap)
        for p, where, kind, okind, m in muts:
            try:
                text = dump(m)
            except Exception:
                continue
            code, err, dt, api = run_one(text, base, parent)
            n += 1
            rec = {"base": base, "path": [str(x) for x in p], "where": where, "kind": kind,
                   "orig": okind, "code": code, "dt": round(dt, 3), "api": api,
                   "err": err[-400:]}
            out.write(json.dumps(rec) + "\n")
        # text-level mutants
        lines = orig_text.splitlines(True)
        texts = []
        top = [i for i, l in enumerate(lines) if l[:1].isalpha()]
        for i in top:     # duplicate each top-level section
            texts.append(("dup_section", "".join(lines) + lines[i]))
        bomb = ("x0: &a0 [1,1,1,1,1,1,1,1,1]\n" + "".join(
            f"x{k}: &a{k} [*a{k-1},*a{k-1},*a{k-1},*a{k-1},*a{k-1},*a{k-1},*a{k-1},*a{k-1},*a{k-1}]\n"
            for k in range(1, 9)))
        texts.append(("alias_bomb_top", bomb + orig_text))
        texts.append(("deep_flow", orig_text + "\nextra: " + "[" * 5000 + "]" * 5000 + "\n"))
        texts.append(("deep_block", orig_text + "\nmetrics:\n" + "".join(" " * (k + 1) + f"k{k}:\n" for k in range(300))))
        texts.append(("bom", "\ufeff" + orig_text))
        texts.append(("crlf", orig_text.replace("\n", "\r\n")))
        texts.append(("truncated", orig_text[: len(orig_text) // 2]))
        for kind, text in texts:
            code, err, dt, api = run_one(text, base, parent)
            n += 1
            out.write(json.dumps({"base": base, "path": [], "where": "text", "kind": kind,
                                  "orig": "text", "code": code, "dt": round(dt, 3), "api": api,
                                  "err": err[-400:]}) + "\n")
        with open(base, "w", encoding="utf-8") as fh:
            fh.write(orig_text)
        print(base, n, flush=True)
    out.close()


def summary(path, sel=""):
    """Print the flagged mutants of ``path`` grouped by (flag, key pattern)."""
    import collections
    import re
    recs = [json.loads(line) for line in open(path)]
    print("mutants", len(recs))
    GEN = re.compile(r"^\d+$")
    def pat(r):
        p = [GEN.sub("#", x) for x in r["path"]]
        if len(p) >= 2 and p[0] in ("blocks", "parameters", "analysis", "metrics", "commands"):
            p[1] = "*"
        if len(p) >= 3 and p[0] == "blocks":
            p[2] = "<param>" if p[2] not in ("type",) else p[2]
        if len(p) >= 4 and p[0] == "commands" and p[2] in ("arguments", "set"):
            p[3] = "*"
        return "/".join(p)
    groups = collections.defaultdict(list)
    for r in recs:
        c = r["code"]
        kinds = []
        if c not in (0, 2):
            kinds.append(f"code {c}")
        if "Traceback" in r["err"] or "internal error" in r["err"]:
            kinds.append("internal")
        if r["api"] not in ("ok", "err"):
            kinds.append("api " + re.sub(r":.*", "", r["api"]))
        if r["dt"] > 10:
            kinds.append("slow")
        if c == 0:
            garbage = (r["kind"] in ("bool", "null", "list", "dict", "deep", "nanstr", "infstr", "float", "str", "unicode", "long") and r["orig"] not in ("bool",) and not (r["kind"]=="float" and r["orig"]=="num")) or r["kind"] in ("alias_bomb_top", "deep_flow", "truncated")
            if r["kind"] in ("str", "unicode", "long") and r["orig"] == "str":
                garbage = False
            if r["where"] == "key" and r["kind"] in ("key_int", "key_bool", "key_null"):
                garbage = True
            if garbage:
                kinds.append("exit0")
        for k in kinds:
            groups[(k, pat(r))].append(r)
    by = collections.Counter()
    for (k, p), rs in groups.items():
        by[k] += len(rs)
    print(dict(by))
    for (k, p), rs in sorted(groups.items()):
        if not k.startswith(sel): continue
        kinds = sorted({r["kind"] for r in rs})
        r = rs[0]
        print(f"{len(rs):4d} {k:12s} {p:45s} {','.join(kinds)[:60]} | {r['base']} {(r['api'] if r['api'] not in ('ok','err') else r['err'][-150:]).strip()[:160]}")


if __name__ == "__main__":
    if sys.argv[1] == "--summary":
        summary(sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else "")
    else:
        main()

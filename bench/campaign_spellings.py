"""The campaign rows of one coupler reached by two names at once, and of one reached by two
protocols at once. Run from bench/campaign.py (campaigns spellings, twoprotocols); C is that module
(run(), outcome(), Tally, Serve).

  spellings  20 kscfg processes at once on one coupler, 10 through HOST=localhost and 10 through
             HOST=127.0.0.1 (tcp://HOST:P against `kscfg serve`, ads://HOST:P against
             `kscfg serve --ads`), writing R33 of either KL3022 channel (5 + 5 writers each), each
             write a value no other writer uses, and reading it back after each write reported
             "written, verified": the read must show that value or one whose write may have come
             after it (ended after this write began, or still going); a value from before is a lost
             verified write (counted as a wrong value), as is a register that ends at a value no
             writer tried. Then no channel may be unlocked, no control byte in register mode (over
             ADS: no byte of the output image written), no code word in the process data.

Before one key per coupler (link/coupler_key.hpp) the two names took two locks and the writers'
sessions undid each other's writes (3 verified writes lost over Modbus, 9 of 300 over ADS).
SPELLINGS_SPLIT_LOCKS=1 gives each name a lock directory of its own, as then: the row's control.

  twoprotocols  10 kscfg at once on one `kscfg serve --tcp --ads`, 5 over tcp:// (the register
             handshake through the process image) and 5 over ads:// (port 100, straight to the
             registers), writing and reading back R33 of either KL3022 channel as above, 50 writes
             each. Then no channel unlocked, no control byte in register mode, no code word in the
             process data, each register at a value some writer tried. serve records that its ADS
             port is the coupler of its Modbus port (link/coupler_key.hpp), so the writers of both
             protocols take one lock and turns; TWOPROTOCOLS_SPLIT_LOCKS=1 hides that record from
             the ADS writers: the row's control.
"""
import os
import random
import threading
import time

import campaign_ads
import campaign_sessions

WRITERS = 20
REG = 33
POS_MODBUS = 4  # KL3022 in the default station (serve: the same position over ADS)


def clean_err(err):
    """stderr without the lines of a wait for the lock (they name the holder; not an error)."""
    return "".join(line for line in err.splitlines(True) if not line.startswith("kscfg: waiting for "))


def spellings(C, proto, writes, seed, work):
    t = C.Tally(f"{WRITERS} kscfg on one coupler, 10 through localhost and 10 through 127.0.0.1, writing R33 of "
                f"two channels {writes} times each and reading it back ({proto} via serve)")
    if proto == "Modbus TCP":
        cp = campaign_sessions.Coupler(C, "serve", work, "spellings-modbus")
        uri_of = {name: cp.uri.replace("127.0.0.1", name) for name in ("localhost", "127.0.0.1")}
        env = cp.env

    else:
        tg = campaign_ads.Target(C, "serve", work, "spellings-ads")
        base = tg.start()
        uri_of = {name: base.replace("127.0.0.1", name) for name in ("localhost", "127.0.0.1")}
        env = tg.env
        image_before = tg.image()

    # SPELLINGS_SPLIT_LOCKS=1: each name its own lock directory, as when the lock was keyed by the
    # name: the control that shows this row can see what it counts.
    envs = {u: env for u in uri_of.values()}
    if os.environ.get("SPELLINGS_SPLIT_LOCKS") == "1":
        envs = {u: dict(env, KSCFG_LOCK_DIR=env["KSCFG_LOCK_DIR"] + "-" + n) for n, u in uri_of.items()}
    counts, ended = contend(C, t, [uri_of["localhost"], uri_of["127.0.0.1"]], envs, WRITERS, writes, seed)

    # The coupler's own state: every register at its writer's last value, nothing left behind.
    if proto == "Modbus TCP":
        regs, out = campaign_sessions.leftovers(cp, t, "the writers")
        got = {ch: regs[(POS_MODBUS, ch)][REG] for ch in (1, 2)}
        for at in range(0, len(out) - 1):
            if out[at] == 0x35 and out[at + 1] == 0x12:
                t.add("wrong value")
                t.note(f"the code word 0x1235 in the output image at byte {at}")
        campaign_sessions.closed(cp, t)
    else:
        for typ, ch in campaign_ads.unlocked(tg):
            t.add("left unlocked")
            t.note(f"{typ} channel {ch} unlocked after the writers")
        tg.stop(t)
        if tg.image() != image_before:
            t.add("left in register mode")
            t.note("a byte of the output image was written over ADS")
        got = {ch: tg.regs("KL3022", ch)[REG] for ch in (1, 2)}
        tg.close()
    ends(t, got, counts, ended)
    return t


def contend(C, t, uris, envs, writers, writes, seed):
    """`writers` kscfg at once, the first half through uris[0] and the rest through uris[1] (each with its
    environment, envs[uri]), writing R33 of either KL3022 channel, each write a value no other writer uses, and
    reading it back after each write reported "written, verified": the read must show that value or one whose
    write may have come after it (ended after this write began, or still going); a value from before is a lost
    verified write (counted as a wrong value). Returns (counts, ended): ended[channel] is (value, end time) of
    every write that ended."""
    def run(uri, args):
        return _kscfg(C, uri, args, envs[uri])

    lock = threading.Lock()
    counts = {"written": 0, "lost": 0, "waited": 0}
    clock = time.monotonic
    # Per register: values being written now, and (value, end time) of every write that ended.
    inflight = {ch: set() for ch in (1, 2)}
    ended = {ch: [(0, 0.0)] for ch in (1, 2)}

    def writer(i):
        rnd = random.Random(seed * 1000 + i)
        uri = uris[0 if i < writers // 2 else 1]
        ch = 1 + i % 2
        sel = ["-t", str(POS_MODBUS), "-c", str(ch)]
        for k in range(writes):
            v = (i + 1) << 8 | (k + rnd.randrange(1, 200)) & 0xFF  # the writer in the high byte: never another's
            with lock:
                inflight[ch].add(v)
            t0 = clock()
            rc, out, err = run(uri, sel + ["write", f"R{REG}", f"0x{v:04X}"])
            with lock:
                inflight[ch].discard(v)
                ended[ch].append((v, clock()))
                t.add("tried")
                counts["waited"] += "kscfg: waiting for " in err
            res = C.outcome(rc, clean_err(err))
            if res != "ok":
                with lock:
                    t.add("crashed" if res == "crashed" else "failed cleanly")
                    t.note(f"writer {i} write: rc {rc}: {err.strip()[:200]}")
                continue
            with lock:
                counts["written"] += 1
            # Read back: its value, or one whose write may have come after it (ended after this one
            # began, or still going). Any other is a value from before: this verified write was undone.
            rc, out, err = run(uri, sel + ["read", "--raw", f"R{REG}"])
            res = C.outcome(rc, clean_err(err))
            if res != "ok":
                with lock:
                    t.add("crashed" if res == "crashed" else "failed cleanly")
                    t.note(f"writer {i} read: rc {rc}: {err.strip()[:200]}")
                continue
            now = int(out.strip(), 16)
            with lock:
                later = inflight[ch] | {x for x, at in ended[ch] if at > t0}
                if now != v and now not in later:
                    counts["lost"] += 1
                    t.add("wrong value")
                    t.note(f"writer {i} ({uri}): R{REG} of channel {ch} reads 0x{now:04X} after its verified "
                           f"write of 0x{v:04X}")

    threads = [threading.Thread(target=writer, args=(i,)) for i in range(writers)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return counts, ended


def ends(t, got, counts, ended):
    """Each register must end at a value some writer tried; the row's note counts the writes."""
    for ch in (1, 2):
        if got[ch] not in {x for x, _ in ended[ch]}:
            t.add("wrong value")
            t.note(f"R{REG} of channel {ch} ends at 0x{got[ch]:04X}, which no writer tried")
    t.note(f"{counts['written']} writes verified, {counts['lost']} of them lost; {counts['waited']} commands waited "
           f"for the coupler and named its holder")


def twoprotocols(C, writers, writes, seed, work):
    """One coupler by two protocols: `serve --tcp --ads` on one station, half the writers over
    Modbus TCP (the image handshake), half over ADS (port 100, straight to the registers), at once."""
    t = C.Tally(f"two protocols on one coupler: {writers} kscfg at once on one `serve --tcp --ads`, {writers // 2} "
                f"over Modbus TCP and {writers // 2} over ADS, writing R33 of the KL3022's two channels {writes} times "
                f"each and reading it back")
    cp = campaign_sessions.Coupler(C, "serve", work, "twoprotocols", serve_args=("--ads", "127.0.0.1:0"))
    ads = cp.srv.p.stdout.readline().strip()
    if not ads.startswith("ads://"):
        raise SystemExit("serve --tcp --ads printed no ADS URI: " + cp.srv.errors())
    # TWOPROTOCOLS_SPLIT_LOCKS=1: the ADS writers look in a lock directory of their own, where serve's
    # record that its ADS port is the coupler of its Modbus port is not: the two protocols then take
    # two locks, as before that record (the row's control).
    ads_env = cp.env
    if os.environ.get("TWOPROTOCOLS_SPLIT_LOCKS") == "1":
        ads_env = dict(cp.env, KSCFG_LOCK_DIR=cp.env["KSCFG_LOCK_DIR"] + "-ads")
    counts, ended = contend(C, t, [cp.uri, ads], {cp.uri: cp.env, ads: ads_env}, writers, writes, seed)
    regs, out = campaign_sessions.leftovers(cp, t, "the writers")
    for at in range(0, len(out) - 1):
        if out[at] == 0x35 and out[at + 1] == 0x12:
            t.add("wrong value")
            t.note(f"the code word 0x1235 in the output image at byte {at}")
    campaign_sessions.closed(cp, t)
    ends(t, {ch: regs[(POS_MODBUS, ch)][REG] for ch in (1, 2)}, counts, ended)
    return t


def _kscfg(C, uri, args, env, timeout=180):
    return C.kscfg_at(uri, args, env, timeout, ("--lock-wait", "120"))[:3]


def run(C, name, seed, work, quick):
    if name == "twoprotocols":
        return [twoprotocols(C, 10, 5 if quick else 50, seed, work)]
    writes = 3 if quick else 15
    return [spellings(C, "Modbus TCP", writes, seed, work), spellings(C, "ADS", writes, seed, work)]

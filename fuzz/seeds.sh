#!/usr/bin/env bash
# Regenerates the seed corpora in fuzz/corpus/ from the built kscfg and the tests' inputs, and
# the regression inputs in fuzz/regressions/ (the crashers the reliability campaign found). The committed files are
# its output; run it after a format changes: fuzz/seeds.sh build/kscfg
set -euo pipefail
K=$(realpath "${1:-build/kscfg}")
cd "$(dirname "$0")"
rm -rf corpus regressions
mkdir -p corpus/{parse,port_uri,station,catalog,state,modbus_requests,journal} \
         regressions/{parse,port_uri,station,catalog,state,modbus_requests,journal}
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT

n=0
for s in R32 r63 32 0x20 0b110 12abc R32-R35 32-35 0xFFFF 65535 65536 "" -1 0x R R64 " 7" 0x0006 R0-R63 R35-R32; do
  printf '%s' "$s" > corpus/parse/$((n++))
done
n=0
for s in emu emu:mem emu:/tmp/state.json "tcp://127.0.0.1" "tcp://127.0.0.1:5020?unit=3" "tcp://[::1]:502" \
         "rtu:/dev/ttyUSB0?baud=19200&parity=E&unit=3" "rtu:/dev/pts/3?parity=N" "rtu:/dev/ttyS0?baud=9600&parity=N&data=7&stop=2" \
         "tcp://" "tcp://127.0.0.1:99999" "tcp://127.0.0.1?unit=300" "rtu:/dev/ttyS0?baud=fast" "udp://127.0.0.1" \
         "ads://10.0.3.11" "ads://127.0.0.1:48898?netid=10.0.3.11.1.1&source=10.0.3.1.1.1" "ads://tv/tt" \
         "ads://h?netid=1.2.3"; do
  printf '%s' "$s" > corpus/port_uri/$((n++))
done

# Station files: the commented example, a backup of the default station, the ones in tests.
"$K" station init "$T/init.toml" >/dev/null
cp "$T/init.toml" corpus/station/init.toml
"$K" --port "emu:$T/s.json" write R32 0x0007 >/dev/null
"$K" --port "emu:$T/s.json" -t 3 write R33 0x0004 >/dev/null
"$K" --port "emu:$T/s.json" backup "$T/backup.toml" >/dev/null 2>&1
cp "$T/backup.toml" corpus/station/backup.toml
printf 'coupler = "BK3120"\n[mapping]\nmotorola = true\n[[terminal]]\ntype = "KL6001"\nbaud = 19200\nR18 = 0x0040\n[[terminal]]\ntype = "KL3022"\n[[terminal.channel]]\nchannel = 2\nR32 = 0x0005\n[[terminal]]\ntype = "KL9010"\n' > corpus/station/channels.toml
printf 'coupler = "BK7300"\n[[terminal]]\ntype = "KL6031"\nbaud = 9600\n[[terminal]]\ntype = "KL1104"\n[[terminal]]\ntype = "KL2134"\n' > corpus/station/rtu.toml
printf 'coupler = "BK9000"\n[[terminal]]\ntype = "KL6001"\n"a.b".c = 1\n' > corpus/station/quoted-key.toml

# Catalog descriptions: a few of every kind.
for t in KL6001 KL6031 KL5101 KL3022 KL1104 KL2134 KL9010 KL4001 KL1501; do
  [ -f "../catalog/$t.toml" ] && cp "../catalog/$t.toml" "corpus/catalog/$t.toml"
done

# Emulator states: fresh, after writes, with faults, with serial data in the FIFOs.
cp "$T/s.json" corpus/state/written.json
"$K" --port "emu:$T/f.json" emu fault -t 1 --ignore-write R33 >/dev/null
"$K" --port "emu:$T/f.json" emu fault -t 3 --mute --delay 3 >/dev/null
cp "$T/f.json" corpus/state/faults.json
"$K" --port "emu:$T/ser.json" serial line none >/dev/null 2>&1 || true
"$K" --port "emu:$T/ser.json" serial send 'hello\r\n' >/dev/null 2>&1 || true
cp "$T/ser.json" corpus/state/serial.json
"$K" --port "emu:$T/r.json" emu reset --station corpus/station/rtu.toml >/dev/null
cp "$T/r.json" corpus/state/rtu.json

# Modbus requests: first byte even = TCP, odd = RTU (fuzz_modbus_requests.cpp); RTU frames get
# their CRC. Regressions: the frames that crashed it once (protocol id 7, length 0 and 65535, FC16 byte
# count that does not match the quantity).
/usr/bin/python3 - <<'PY'
def crc(b):
    c = 0xFFFF
    for x in b:
        c ^= x
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
    return bytes([c & 0xFF, c >> 8])
def tcp(tid, pdu, unit=1, proto=0, length=None):
    n = len(pdu) + 1 if length is None else length
    return bytes([tid >> 8, tid & 0xFF, proto >> 8, proto & 0xFF, n >> 8, n & 0xFF, unit]) + bytes(pdu)
def rtu(pdu, unit=1):
    f = bytes([unit]) + bytes(pdu)
    return f + crc(f)
C = "corpus/modbus_requests/"
R = "regressions/modbus_requests/"
seeds = {
    C + "tcp-fc3-ident": b"\0" + tcp(1, [3, 0x10, 0x00, 0, 7]),
    C + "tcp-fc4-lengths": b"\0" + tcp(2, [4, 0x10, 0x10, 0, 4]),
    C + "tcp-fc3-inputs": b"\0" + tcp(3, [3, 0, 0, 0, 16]),
    C + "tcp-fc16-outputs": b"\0" + tcp(4, [16, 0x08, 0, 0, 2, 4, 0xA0, 0, 0, 0]),
    C + "tcp-fc6-watchdog": b"\0" + tcp(5, [6, 0x11, 0x20, 0x03, 0xE8]),
    C + "tcp-fc23": b"\0" + tcp(6, [23, 0, 0, 0, 4, 0x08, 0, 0, 2, 4, 0xC1, 0, 0, 0]),
    C + "tcp-pipelined": b"\0" + tcp(7, [3, 0x10, 0, 0, 7]) + tcp(8, [3, 0x08, 0, 0, 4]),
    C + "rtu-fc3": b"\1" + rtu([3, 0x10, 0, 0, 7]),
    C + "rtu-fc16": b"\1" + rtu([16, 0x08, 0, 0, 1, 2, 0xA0, 0]),
    C + "rtu-fc23": b"\1" + rtu([23, 0, 0, 0, 2, 0x08, 0, 0, 1, 2, 0xC1, 0]),
    C + "rtu-broadcast": b"\1" + rtu([6, 0x08, 0, 0, 0x42], unit=0),
    R + "tcp-protocol-id-7": b"\0" + tcp(1, [3, 0x10, 0, 0, 7], proto=7),
    R + "tcp-length-0": b"\0" + tcp(1, [3, 0x10, 0, 0, 7], length=0),
    R + "tcp-length-65535": b"\0" + tcp(1, [3, 0x10, 0, 0, 7], length=65535),
    R + "tcp-fc16-bytecount": b"\0" + tcp(1, [16, 0x08, 0, 0, 2, 3, 0, 0, 0]),
    R + "rtu-fc16-bytecount": b"\1" + rtu([16, 0x08, 0, 0, 2, 3, 0, 0, 0]),
}
for name, data in seeds.items():
    open(name, "wb").write(data)
PY

# Regressions: the 80 KB key of 40 000 dotted parts (station, catalog, the station in a state),
# nesting, and the corrupt numbers of a state file.
/usr/bin/python3 - "$T/s.json" <<'PY'
import json, sys
dots = "a" + ".a" * 39999 + " = 1\n"
open("regressions/station/dots-40000.toml", "w").write(dots)
open("regressions/catalog/dots-40000.toml", "w").write(dots)
open("regressions/station/nested-300.toml", "w").write("x = " + "[" * 300 + "]" * 300 + "\n")
# The station whose image exceeds the 512-byte register map (emu reset took it; serve overflowed).
open("regressions/station/image-600-bytes.toml", "w").write('coupler = "BK9000"\n' + '[[terminal]]\ntype = "KL3022"\n' * 100 + '[[terminal]]\ntype = "KL9010"\n')
s = json.load(open(sys.argv[1]))
def variant(name, f):
    j = json.loads(json.dumps(s)); f(j); open("regressions/state/" + name, "w").write(json.dumps(j, indent=1))
variant("registers-1e30.json", lambda j: j["channels"][0]["registers"].__setitem__(32, 1e30))
variant("prev-status-300.json", lambda j: j["channels"][0]["serial"].__setitem__("prev_status", 300))
variant("station-dots.json", lambda j: j.__setitem__("station", dots))
variant("response-delay-float.json", lambda j: j.__setitem__("response_delay", 2.5))
# Found by fuzz_state: a station naming a type the catalog does not know (was exit 2, not 7).
variant("station-unknown-type.json", lambda j: j.__setitem__("station", j["station"].replace("KL6001", "KL4505")))
PY
# Session journals (fuzz_journal.cpp): what kscfg writes (entered, control bytes, left), one cut
# by a kill -9 inside a line, and forged ones (offsets beyond the image, huge positions).
printf '+ 1 0 0 0 2 3 2 3 0 0000000000000000 KL6001\n> 1 0 88\n> 1 0 9f\n- 1 0\n' > corpus/journal/left
printf '+ 3 0 16 16 18 19 18 19 16 000041420000000000000000000000000000000000000000 KL6031\n> 3 0 df\n> 3 0 a0\n> 3 0 88\n' > corpus/journal/open
printf '+ 4 1 44 44 46 47 46 47 44 00000000 KL3022\n> 4 1 a4\n+ 2 0 8 8 10 11 10 11 8 0000000000000000 ?\n> 2 0 8' > corpus/journal/cut
printf '+ 1 0 600 0 2 3 2 3 0 00 KL6001\n+ 99999 0 0 0 2 3 2 3 0 00 KL6001\n> 1 0 zz\n- 1\n' > regressions/journal/forged
# A relock that failed ("!") and outputs a `data force` left forced ("f", "r" once back).
printf '+ 1 0 0 0 2 3 2 3 0 00 KL6001\n> 1 0 a0\n> 1 0 df\n> 1 0 00\n> 1 0 df\n! 1 0\n> 1 0 00\n' > corpus/journal/relock-failed
printf 'f 6 0 7 05 00 05 KL2134\nf 6 0 6 01 00 01 KL2134\nr 6 0 6\nf 3 1 20 ff 10 27 KL4032\n' > corpus/journal/forced

echo "seeds: $(find corpus -type f | wc -l) corpus files, $(find regressions -type f | wc -l) regression inputs"

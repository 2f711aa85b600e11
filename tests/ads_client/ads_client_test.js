// The npm package ads-client (raw mode, no router) drives `kscfg serve --ads` through ports 100
// and 300: a client kscfg did not make. Usage: node ads_client_test.js PORT [RESULT_FILE]
// Prints "ok ..." / "FAIL ..." lines; exit status 1 when anything failed. Run by run_ads_client.py.
'use strict';
const { Client } = require('ads-client');

const port = Number(process.argv[2]);
let failed = 0;
function check(cond, what) {
  console.log((cond ? 'ok   ' : 'FAIL ') + what);
  if (!cond) failed++;
}

(async () => {
  const client = new Client({
    targetAmsNetId: '127.0.0.1.1.1', // the coupler: its IP address plus .1.1
    targetAdsPort: 100,
    routerAddress: '127.0.0.1',
    routerTcpPort: port,
    localAmsNetId: '127.0.0.1.1.1',
    localAdsPort: 32750,
    rawClient: true, // no PLC runtime, no router: ReadState and symbols are never asked for
    timeoutDelay: 3000,
  });
  try {
    await client.connect();
    const info = await client.readDeviceInfo();
    check(info.deviceName === 'BK9000', `ReadDeviceInfo on port 100: ${info.deviceName}`);

    // Port 100: terminal number 1 (the KL6001), channel 0, R8; index group 0 table 9.
    const r8 = await client.readRaw(1, 8, 2);
    check(r8.readUInt16LE(0) === 6001, `port 100 terminal 1 R8 = ${r8.readUInt16LE(0)}`);
    const t9 = await client.readRaw(0, (9 << 16) | 0, 2);
    check(t9.readUInt16LE(0) === 9000, `port 100 table 9 register 0 = ${t9.readUInt16LE(0)}`);
    const kl3022 = await client.readRaw(4, (1 << 16) | 8, 2);
    check(kl3022.readUInt16LE(0) === 3022, `port 100 terminal 4 channel 2 R8 = ${kl3022.readUInt16LE(0)}`);

    // A write with the code word, read back; left at the new value for run_ads_client.py to find.
    const word = (v) => { const b = Buffer.alloc(2); b.writeUInt16LE(v); return b; };
    const before = (await client.readRaw(1, 32, 2)).readUInt16LE(0);
    await client.writeRaw(1, 31, word(0x1235));
    await client.writeRaw(1, 32, word(before ^ 0x0001));
    await client.writeRaw(1, 31, word(0));
    const after = (await client.readRaw(1, 32, 2)).readUInt16LE(0);
    check(after === (before ^ 1), `port 100 terminal 1 R32 ${before} -> ${after} with the code word`);
    console.log(`R32=${after}`);

    // Errors by code: no terminal 40, tables read only.
    try { await client.readRaw(40, 8, 2); check(false, 'terminal 40 refused'); }
    catch (e) { const why = JSON.stringify(e.adsError || {}); check(why.includes('1794'), `terminal 40 refused with ADS error 1794 (0x702): ${e.message} ${why}`); }

    // Port 300: the output image written and read back, the inputs read.
    const p300 = { adsPort: 300 };
    const out = await client.readRaw(0xF030, 0, 4, p300);
    check(out.length === 4, `port 300 outputs read: ${out.toString('hex')}`);
    const inputs = await client.readRaw(0xF020, 0, 8, p300);
    check(inputs.length === 8, `port 300 inputs read: ${inputs.toString('hex')}`);

    // ReadState is refused as a BK9050 refuses it (AMS error 0x8, unknown command ID).
    try { await client.readState(); check(false, 'ReadState refused'); }
    catch (e) { const why = JSON.stringify(e.adsError || {}) + ' ' + String(e.cause || ''); check(/unknown command|\b8\b|0x8/i.test(why), `ReadState refused: ${e.message} ${why}`); }
  } catch (e) {
    check(false, `unexpected: ${e.stack || e}`);
  } finally {
    try { await client.disconnect(); } catch (e) { /* closing only */ }
  }
  console.log(failed ? `${failed} failed` : 'all passed');
  process.exit(failed ? 1 : 0);
})();

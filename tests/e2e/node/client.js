// One session of Node modbus-serial against the virtual drive, as a Node-RED
// flow or a Node HMI makes it: connect with the method named, read the
// statusword, write and read back 0x6083, read a register that does not
// exist. Prints what it got as one JSON line; exit 1 on any failure.
//   node client.js connectTCP|connectTcpRTUBuffered|connectTelnet PORT [UNIT]
"use strict";
const ModbusRTU = require("modbus-serial");

const [method, port, unit = "1"] = process.argv.slice(2);

(async () => {
  const c = new ModbusRTU();
  await c[method]("127.0.0.1", { port: Number(port) });
  c.setID(Number(unit));
  c.setTimeout(2000);
  const sw = await c.readHoldingRegisters(0x6041, 1);
  await c.writeRegister(0x6083, 4321);
  const acc = await c.readHoldingRegisters(0x6083, 1);
  let missing = null;
  try {
    await c.readHoldingRegisters(0x6042, 1);
  } catch (e) {
    missing = e.modbusCode === undefined ? String(e) : e.modbusCode;
  }
  console.log(JSON.stringify({ sw: sw.data[0], acc: acc.data[0], missing }));
  c.close(() => process.exit(0));
})().catch((e) => {
  console.error(String(e && e.message ? e.message : e));
  process.exit(1);
});

"""A USB host for the emulated OTG FS device: enumeration as Linux does it, the CDC-ACM rules
that Linux's cdc_acm relies on, and bulk transfers (the pty bridge is usbbridge.py).

The host works transaction by transaction against :class:`uwbcal.evk1000.otgfs.OtgFs`. Between
transactions it lets the device run (``runner.run_us``): on the emulated EVK1000 that is CPU
time with interrupts; in the host-side harness (usbhosted.py) it is the driver's interrupt
handler. Every wait is bounded in device time (USB 2.0 9.2.6.4: a control request completes
within 5 s; Linux uses USB_CTRL_GET_TIMEOUT = 5 s), so a device that stops answering raises
:class:`UsbError` instead of hanging.

Every descriptor is parsed with the PyPI package ``usb-protocol`` (an independent parser the
project did not write); :func:`check_cdc_acm` then checks what cdc_acm needs.
Units: time in microseconds of device time, sizes in bytes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

from uwbcal.errors import UwbcalError
from uwbcal.evk1000.otgfs import InResult, OtgFs

#: Device time a NAKed transaction waits before it is retried (one full-speed frame), us.
FRAME_US: Final = 1000
#: Longest a control transfer may take (Linux USB_CTRL_GET_TIMEOUT), us.
CTRL_TIMEOUT_US: Final = 5_000_000
#: Bus reset length (USB 2.0 7.1.7.5: at least 10 ms), us.
RESET_US: Final = 10_000

GET_STATUS, CLEAR_FEATURE, SET_FEATURE, SET_ADDRESS, GET_DESCRIPTOR = 0, 1, 3, 5, 6
GET_CONFIGURATION, SET_CONFIGURATION = 8, 9
SET_LINE_CODING, GET_LINE_CODING, SET_CONTROL_LINE_STATE = 0x20, 0x21, 0x22
DT_DEVICE, DT_CONFIG, DT_STRING, DT_INTERFACE, DT_ENDPOINT, DT_IAD, DT_CS_INTERFACE = 1, 2, 3, 4, 5, 11, 0x24


class UsbError(UwbcalError):
    """The emulated USB device misbehaved: a timeout, an unexpected STALL, a bad descriptor."""

    exit_code = 10


class UsbStall(UsbError):
    """The device answered a control request with STALL (a request error, USB 2.0 8.5.3.4)."""


class DeviceRunner(Protocol):
    """Lets the device run for some microseconds of its own time."""

    def run_us(self, us: int) -> None: ...


def setup_packet(bm: int, req: int, value: int, index: int, length: int) -> bytes:
    """The 8-byte SETUP packet of USB 2.0 9.3."""
    return struct.pack("<BBHHH", bm, req, value, index, length)


@dataclass
class Enumeration:
    """What enumeration found: the raw descriptors and their parsed forms."""

    address: int
    device: Any
    config_raw: bytes
    config: list[Any]
    strings: dict[int, str] = field(default_factory=dict)

    @property
    def vid(self) -> int:
        return int(self.device.idVendor)

    @property
    def pid(self) -> int:
        return int(self.device.idProduct)

    @property
    def serial(self) -> str:
        return self.strings.get(int(self.device.iSerialNumber), "")


class UsbHost:
    """The host controller and the kernel's hub/core driver, for one device on one port."""

    def __init__(self, dev: OtgFs, runner: DeviceRunner) -> None:
        self.dev = dev
        self.runner = runner
        self.addr = 0
        self.toggle_in: dict[int, int] = {}
        self.toggle_out: dict[int, int] = {}
        self.time_us = 0

    def run(self, us: int) -> None:
        self.runner.run_us(us)
        self.time_us += us

    # ---- bus -----------------------------------------------------------------------------------
    def wait_connect(self, timeout_us: int = 2_000_000) -> None:
        """Wait until the device's D+ pull-up is on (it finished its init)."""
        waited = 0
        while not self.dev.connected:
            if waited >= timeout_us:
                raise UsbError(f"USB: no device attached after {timeout_us / 1e6:.1f} s (D+ pull-up off)")
            self.run(FRAME_US)
            waited += FRAME_US
        # USB 2.0 7.1.7.3: the host waits 100 ms after attach before resetting.
        self.run(100_000)

    def bus_reset(self) -> None:
        """Reset the port: the device goes back to address 0, unconfigured."""
        self.dev.bus_reset()
        self.run(RESET_US)
        self.addr = 0
        self.toggle_in.clear()
        self.toggle_out.clear()
        self.run(10_000)  # reset recovery, USB 2.0 7.1.7.5

    # ---- transactions with retries ---------------------------------------------------------------
    def _in(self, ep: int, deadline: int) -> InResult:
        while True:
            r = self.dev.in_token(self.addr, ep)
            if r.handshake == "ACK":
                return r
            if r.handshake in ("STALL", "TIMEOUT"):
                return r
            if self.time_us >= deadline:
                return r
            self.run(FRAME_US)

    def _out(self, ep: int, data: bytes, pid: int, deadline: int) -> str:
        while True:
            h = self.dev.out(self.addr, ep, data, pid)
            if h != "NAK" or self.time_us >= deadline:
                return h
            self.run(FRAME_US)

    def control(self, bm: int, req: int, value: int, index: int, length: int, data: bytes = b"") -> bytes:
        """One control transfer on EP0 (SETUP, data stage, status stage). Returns IN data."""
        deadline = self.time_us + CTRL_TIMEOUT_US
        what = f"request 0x{bm:02X}/0x{req:02X} value 0x{value:04X} index {index}"
        if self.dev.setup(self.addr, setup_packet(bm, req, value, index, length)) != "ACK":
            raise UsbError(f"USB: SETUP of {what} not acknowledged (device at address {self.addr}?)")
        self.run(50)
        got = bytearray()
        pid = 1
        if bm & 0x80:
            while len(got) < length:
                r = self._in(0, deadline)
                if r.handshake == "STALL":
                    raise UsbStall(f"USB: {what}: STALL")
                if r.handshake != "ACK":
                    raise UsbError(f"USB: {what}: data stage {r.handshake} (limit {CTRL_TIMEOUT_US} us)")
                if r.pid != pid:
                    raise UsbError(f"USB: {what}: data stage packet DATA{r.pid}, expected DATA{pid}")
                pid ^= 1
                got += r.data
                if len(r.data) < 64:
                    break
            h = self._out(0, b"", 1, deadline)
            if h == "STALL":  # a request error may show first in the status stage (8.5.3.4)
                raise UsbStall(f"USB: {what}: STALL in the status stage")
            if h != "ACK":
                raise UsbError(f"USB: {what}: status stage {h}")
            return bytes(got)
        for i in range(0, len(data), 64):
            h = self._out(0, data[i:i + 64], pid, deadline)
            if h == "STALL":
                raise UsbStall(f"USB: {what}: STALL")
            if h != "ACK":
                raise UsbError(f"USB: {what}: data stage {h}")
            pid ^= 1
        r = self._in(0, deadline)
        if r.handshake == "STALL":
            raise UsbStall(f"USB: {what}: STALL")
        if r.handshake != "ACK" or r.data or r.pid != 1:
            raise UsbError(f"USB: {what}: status stage {r.handshake} ({len(r.data)} bytes, DATA{r.pid})")
        # USB 2.0 9.4.5 / 9.1.1.5: SET_CONFIGURATION and CLEAR_FEATURE(ENDPOINT_HALT) put the
        # data toggle back to DATA0, on the host's side as on the device's.
        if req == SET_CONFIGURATION and bm == 0x00:
            self.toggle_in.clear()
            self.toggle_out.clear()
        elif req == CLEAR_FEATURE and bm == 0x02 and value == 0:
            (self.toggle_in if index & 0x80 else self.toggle_out).pop(index & 0x0F, None)
        return b""

    def get_descriptor(self, dtype: int, index: int, length: int, langid: int = 0) -> bytes:
        return self.control(0x80, GET_DESCRIPTOR, (dtype << 8) | index, langid, length)

    # ---- enumeration, as Linux's hub driver and usb core do it ---------------------------------
    def enumerate(self) -> Enumeration:
        """Reset, GET_DESCRIPTOR(device, 64), reset, SET_ADDRESS, GET_DESCRIPTOR(device, 18),
        configuration (9 bytes, then wTotalLength), strings (language IDs, then each index, 255
        bytes), SET_CONFIGURATION 1 (hub.c hub_port_init "new scheme", message.c, generic.c)."""
        from usb_protocol.types.descriptors import standard as std

        self.wait_connect()
        self.bus_reset()
        head = self.get_descriptor(DT_DEVICE, 0, 64)
        if len(head) < 8 or head[1] != DT_DEVICE:
            raise UsbError(f"USB: first device descriptor read gave {head.hex()}")
        self.bus_reset()
        address = 1 + (self.time_us // 1000) % 126  # like a hub's next free address
        self.control(0x00, SET_ADDRESS, address, 0, 0)
        self.addr = address
        self.run(2_000)  # SET_ADDRESS recovery, USB 2.0 9.2.6.3
        raw = self.get_descriptor(DT_DEVICE, 0, 18)
        device = _parse(std.DeviceDescriptor, raw, "device descriptor")
        cfg9 = self.get_descriptor(DT_CONFIG, 0, 9)
        total = struct.unpack_from("<H", cfg9, 2)[0] if len(cfg9) >= 4 else 0
        cfg = self.get_descriptor(DT_CONFIG, 0, total)
        if len(cfg) != total:
            raise UsbError(f"USB: configuration descriptor {len(cfg)} bytes, wTotalLength says {total}")
        parsed = parse_configuration(cfg)
        strings: dict[int, str] = {}
        langs = _parse(std.StringLanguageDescriptor, self.get_descriptor(DT_STRING, 0, 255), "string 0")
        langid = int(langs.wLANGID[0])
        for idx in (device.iManufacturer, device.iProduct, device.iSerialNumber):
            if idx:
                raw_s = self.get_descriptor(DT_STRING, idx, 255, langid)
                s = _parse(std.StringDescriptor, raw_s, f"string {idx}")
                strings[int(idx)] = str(s.bString)
        self.control(0x00, SET_CONFIGURATION, int(parsed[0].bConfigurationValue), 0, 0)
        return Enumeration(address, device, cfg, parsed, strings)

    def port_reset(self) -> Enumeration:
        """What Linux's usb_reset_device does (error recovery, or a USBDEVFS_RESET): reset the
        port, enumerate again without the attach debounce, check the descriptors did not
        change, restore the configuration. The tty of cdc_acm stays."""
        from usb_protocol.types.descriptors import standard as std

        old = self.addr
        self.bus_reset()
        head = self.get_descriptor(DT_DEVICE, 0, 64)
        if len(head) < 8 or head[1] != DT_DEVICE:
            raise UsbError(f"USB: device descriptor after reset: {head.hex()}")
        self.bus_reset()
        self.control(0x00, SET_ADDRESS, old, 0, 0)
        self.addr = old
        self.run(2_000)
        raw = self.get_descriptor(DT_DEVICE, 0, 18)
        device = _parse(std.DeviceDescriptor, raw, "device descriptor")
        cfg9 = self.get_descriptor(DT_CONFIG, 0, 9)
        cfg = self.get_descriptor(DT_CONFIG, 0, struct.unpack_from("<H", cfg9, 2)[0])
        parsed = parse_configuration(cfg)
        self.control(0x00, SET_CONFIGURATION, int(parsed[0].bConfigurationValue), 0, 0)
        return Enumeration(old, device, cfg, parsed)

    def cdc_open(self, baud: int = 115200) -> None:
        """What cdc_acm does when a program opens /dev/ttyACM0: line coding, then DTR and RTS."""
        self.control(0x21, SET_LINE_CODING, 0, 0, 7, struct.pack("<IBBB", baud, 0, 0, 8))
        self.control(0x21, SET_CONTROL_LINE_STATE, 0x3, 0, 0)

    # ---- bulk ---------------------------------------------------------------------------------------
    def bulk_out(self, ep: int, data: bytes, timeout_us: int = 1_000_000) -> int:
        """Send ``data`` as 64-byte packets (a ZLP when it ends on a full packet); returns bytes
        the device accepted before ``timeout_us`` of NAKs."""
        deadline = self.time_us + timeout_us
        sent = 0
        chunks = [data[i:i + 64] for i in range(0, len(data), 64)]
        if data and len(data) % 64 == 0:
            chunks.append(b"")
        for c in chunks:
            pid = self.toggle_out.get(ep, 0)
            h = self._out(ep, c, pid, deadline)
            if h == "STALL":
                raise UsbError(f"USB: bulk OUT EP{ep} STALLed")
            if h != "ACK":
                break
            self.toggle_out[ep] = pid ^ 1
            sent += len(c)
        return sent

    def bulk_in_packet(self, ep: int) -> bytes | None:
        """One IN token to endpoint ``ep`` (number or address): the packet (possibly empty), or
        None when the device NAKs."""
        ep &= 0x0F
        r = self.dev.in_token(self.addr, ep)
        if r.handshake == "NAK" or r.handshake == "TIMEOUT":
            return None
        if r.handshake == "STALL":
            raise UsbError(f"USB: bulk IN EP{ep & 0xF} STALLed")
        want = self.toggle_in.get(ep, 0)
        if r.pid != want:
            return b""  # a repeated packet (our ACK was lost): ignored, USB 2.0 8.6.4
        self.toggle_in[ep] = want ^ 1
        return r.data

    def bulk_in(self, ep: int, max_bytes: int, idle_us: int = 20_000) -> bytes:
        """Read like cdc_acm's read URB: packets until a short one or ``max_bytes``; gives up
        after ``idle_us`` of NAKs."""
        got = bytearray()
        waited = 0
        while len(got) < max_bytes:
            p = self.bulk_in_packet(ep)
            if p is None:
                if got or waited >= idle_us:
                    break
                self.run(FRAME_US)
                waited += FRAME_US
                continue
            got += p
            if len(p) < 64:
                break
        return bytes(got)


def _parse(fmt: Any, raw: bytes, what: str) -> Any:
    try:
        return fmt.parse(raw)
    except Exception as e:  # construct raises several error types
        raise UsbError(f"USB: {what} does not parse ({e.__class__.__name__}: {e}): {raw.hex()}") from None


def parse_configuration(raw: bytes) -> list[Any]:
    """Split a configuration descriptor set into its descriptors and parse each one with
    usb-protocol's formats (standard and CDC). Unknown types are an error here: this device
    has none."""
    from usb_protocol.types.descriptors import cdc
    from usb_protocol.types.descriptors import standard as std

    cs = {0x00: cdc.HeaderDescriptor, 0x01: cdc.CallManagementFunctionalDescriptor,
          0x02: cdc.ACMFunctionalDescriptor, 0x06: cdc.UnionFunctionalDescriptor}
    fmts = {DT_CONFIG: std.ConfigurationDescriptor, DT_INTERFACE: std.InterfaceDescriptor,
            DT_ENDPOINT: std.EndpointDescriptor, DT_IAD: std.InterfaceAssociationDescriptor}
    out: list[Any] = []
    i = 0
    while i < len(raw):
        n = raw[i]
        if n < 2 or i + n > len(raw):
            raise UsbError(f"USB: descriptor at offset {i} has bLength {n} (set of {len(raw)} bytes)")
        d = raw[i:i + n]
        fmt = cs.get(d[2]) if d[1] == DT_CS_INTERFACE and n >= 3 else fmts.get(d[1])
        if fmt is None:
            raise UsbError(f"USB: descriptor type 0x{d[1]:02X} at offset {i}: not one this device has")
        out.append(_parse(fmt, d, f"descriptor at offset {i}"))
        i += n
    return out


def check_cdc_acm(e: Enumeration) -> list[str]:
    """The USB 2.0 and CDC 1.2 rules Linux's cdc_acm (drivers/usb/class/cdc-acm.c, and the IAD
    handling of usb core) relies on. Returns the problems found; empty means none."""
    bad: list[str] = []
    d = e.device
    if float(d.bcdUSB) < 2.0:
        bad.append(f"bcdUSB {d.bcdUSB}: 2.00 expected")
    if d.bMaxPacketSize0 != 64:
        bad.append(f"bMaxPacketSize0 {d.bMaxPacketSize0}: a full-speed device should use 64")
    if (d.bDeviceClass, d.bDeviceSubclass, d.bDeviceProtocol) != (0xEF, 0x02, 0x01):
        bad.append("device class should be 0xEF/0x02/0x01 (IAD) for a composite CDC function")
    if d.bNumConfigurations != 1:
        bad.append(f"bNumConfigurations {d.bNumConfigurations}")
    if not e.serial:
        bad.append("no serial number string: udev and `uwbcal ports` cannot tell boards apart")
    cfg = e.config[0]
    if cfg.wTotalLength != len(e.config_raw):
        bad.append(f"wTotalLength {cfg.wTotalLength} != {len(e.config_raw)} bytes read")
    if cfg.bmAttributes & 0x80 == 0:
        bad.append("configuration bmAttributes bit 7 must be set (USB 2.0 9.6.3)")
    if cfg.bMaxPower > 250:
        bad.append(f"bMaxPower {cfg.bMaxPower * 2} mA > 500 mA")
    intfs = [x for x in e.config if x.bDescriptorType == DT_INTERFACE]
    if len(intfs) != cfg.bNumInterfaces:
        bad.append(f"{len(intfs)} interfaces, bNumInterfaces says {cfg.bNumInterfaces}")
    iads = [x for x in e.config if x.bDescriptorType == DT_IAD]
    if len(iads) != 1 or iads[0].bFirstInterface != 0 or iads[0].bInterfaceCount != 2:
        bad.append("one IAD over interfaces 0-1 expected")
    elif (iads[0].bFunctionClass, iads[0].bFunctionSubClass) != (0x02, 0x02):
        bad.append("IAD function class should be CDC (0x02) / ACM (0x02)")
    comm = [x for x in intfs if x.bInterfaceClass == 0x02 and x.bInterfaceSubclass == 0x02]
    data = [x for x in intfs if x.bInterfaceClass == 0x0A]
    if len(comm) != 1 or len(data) != 1:
        return bad + ["one CDC ACM communications interface and one CDC data interface expected"]
    # Class-specific descriptors follow the communications interface, before its endpoint.
    idx = e.config.index(comm[0])
    cs_list = []
    for x in e.config[idx + 1:]:
        if x.bDescriptorType != DT_CS_INTERFACE:
            break
        cs_list.append(x)
    subtypes = [x.bDescriptorSubtype for x in cs_list]
    if not subtypes or subtypes[0] != 0x00:
        bad.append("the CDC Header functional descriptor must come first (CDC 1.2 5.2.3)")
    unions = [x for x in cs_list if x.bDescriptorSubtype == 0x06]
    if len(unions) != 1:
        bad.append("a Union functional descriptor is required (cdc_acm probes with it)")
    elif (unions[0].bControlInterface, unions[0].bSubordinateInterface0) != (
            comm[0].bInterfaceNumber, data[0].bInterfaceNumber):
        bad.append("the Union descriptor must name the communications then the data interface")
    acm = [x for x in cs_list if x.bDescriptorSubtype == 0x02]
    if len(acm) != 1 or not acm[0].bmCapabilities & 0x02:
        bad.append("ACM descriptor must announce line coding / control line state (bmCapabilities bit 1)")
    cm = [x for x in cs_list if x.bDescriptorSubtype == 0x01]
    if cm and cm[0].bDataInterface != data[0].bInterfaceNumber:
        bad.append("Call Management bDataInterface must be the data interface")
    eps = [x for x in e.config if x.bDescriptorType == DT_ENDPOINT]
    comm_eps = eps[:comm[0].bNumEndpoints]
    if len(comm_eps) != 1 or comm_eps[0].bmAttributes & 3 != 3 or not comm_eps[0].bEndpointAddress & 0x80:
        bad.append("the communications interface needs one interrupt IN endpoint")
    data_eps = eps[comm[0].bNumEndpoints:]
    kinds = sorted((x.bEndpointAddress & 0x80, x.bmAttributes & 3, x.wMaxPacketSize) for x in data_eps)
    if kinds != [(0x00, 2, 64), (0x80, 2, 64)]:
        bad.append(f"the data interface needs bulk IN and bulk OUT of 64 bytes, has {kinds}")
    addrs = [x.bEndpointAddress for x in eps]
    if len(set(addrs)) != len(addrs):
        bad.append("endpoint addresses repeat")
    return bad

//! ArNetworking packets: framing, checksum and payload fields.
//!
//! A packet is `0x0F 0x0C` (sync), `length u16 LE` (the whole packet, sync to checksum),
//! `command u16 LE`, the payload, then a 2-byte checksum **high byte first**. The checksum is
//! the protocol's own 16-bit sum, kept with its quirks: it starts at byte 3 (the length's high
//! byte, skipping its low byte) and, for an odd payload, XORs in one byte and never covers the
//! last payload byte (see [`checksum`]).
//!
//! Payload fields: integers little-endian; strings NUL-terminated; a double is a NUL-terminated
//! C `%g` string (`INF`, `-INF` for infinities), see [`format_g`].

use thiserror::Error;

/// The two sync bytes that open every packet.
pub const SYNC: [u8; 2] = [0x0F, 0x0C];

/// Bytes of a packet without payload: sync 2, length 2, command 2, checksum 2.
pub const HEADER_LEN: usize = 6;

/// Smallest packet: header and checksum, no payload.
pub const MIN_PACKET_LEN: usize = HEADER_LEN + 2;

/// Largest packet this codec accepts or builds, bytes. ARIA's packets are bounded well below
/// the u16 length field; *uncertain* for ARAM, so a generous bound: anything longer is a
/// framing error, not a reason to buffer without limit.
pub const MAX_PACKET_LEN: usize = 32_000;

/// A bad packet or payload field. Each is a typed, counted error: the driver never turns one
/// into a motion command.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum PacketError {
    /// The first two bytes were not `0x0F 0x0C`.
    #[error("bad sync bytes {0:02x} {1:02x} (expected 0f 0c)")]
    BadSync(u8, u8),
    /// The length field is below the minimum or above [`MAX_PACKET_LEN`].
    #[error("bad packet length {0} (must be {MIN_PACKET_LEN}..={MAX_PACKET_LEN})")]
    BadLength(usize),
    /// The checksum did not match.
    #[error("bad checksum on command {command}: got {got:04x}, computed {computed:04x}")]
    BadChecksum {
        /// The packet's command number.
        command: u16,
        /// Checksum carried by the packet.
        got: u16,
        /// Checksum computed over the packet.
        computed: u16,
    },
    /// The buffer ends inside a packet (a stream that closed mid-packet).
    #[error("truncated packet: {have} of {need} bytes")]
    Truncated {
        /// Bytes available.
        have: usize,
        /// Bytes the length field asks for.
        need: usize,
    },
    /// A payload field ran past the payload's end.
    #[error("payload too short reading {field}")]
    ShortPayload {
        /// The field being read.
        field: &'static str,
    },
    /// A string field had no terminating NUL, or a double was not a number.
    #[error("bad {field} field: {detail}")]
    BadField {
        /// The field being read.
        field: &'static str,
        /// What was wrong.
        detail: String,
    },
    /// A payload too long for one packet.
    #[error("payload of {0} bytes does not fit in a packet")]
    TooLong(usize),
}

/// The protocol's checksum of `bytes`, a packet without its two checksum bytes.
///
/// `c = 0; i = 3; n = len − 2; while n > 3 { c += b[i] << 8 | b[i+1]; n −= 2; i += 2 };
/// if n > 0 { c ^= b[i] }`, all mod 2^16.
pub fn checksum(bytes: &[u8]) -> u16 {
    let mut c: u16 = 0;
    let mut i = 3;
    let mut n = bytes.len() as isize - 2;
    while n > 3 {
        c = c.wrapping_add(u16::from(bytes[i]) << 8 | u16::from(bytes[i + 1]));
        n -= 2;
        i += 2;
    }
    if n > 0 {
        c ^= u16::from(bytes[i]);
    }
    c
}

/// One ArNetworking packet: its command number and payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet {
    /// Command number (a fixed command, or a named data number from 256 up).
    pub command: u16,
    /// Payload bytes.
    pub payload: Vec<u8>,
}

impl Packet {
    /// A packet with `command` and `payload`.
    pub fn new(command: u16, payload: Vec<u8>) -> Self {
        Self { command, payload }
    }

    /// A packet with `command` and no payload.
    pub fn empty(command: u16) -> Self {
        Self::new(command, Vec::new())
    }

    /// The packet's bytes on the wire.
    pub fn encode(&self) -> Result<Vec<u8>, PacketError> {
        let len = MIN_PACKET_LEN + self.payload.len();
        if len > MAX_PACKET_LEN {
            return Err(PacketError::TooLong(self.payload.len()));
        }
        let mut out = Vec::with_capacity(len);
        out.extend_from_slice(&SYNC);
        out.extend_from_slice(&(len as u16).to_le_bytes());
        out.extend_from_slice(&self.command.to_le_bytes());
        out.extend_from_slice(&self.payload);
        let c = checksum(&out);
        out.extend_from_slice(&c.to_be_bytes());
        Ok(out)
    }

    /// Decodes the first packet in `buf`: `Ok(None)` while `buf` holds only part of one,
    /// else the packet and the bytes it took.
    pub fn decode(buf: &[u8]) -> Result<Option<(Packet, usize)>, PacketError> {
        if buf.len() >= 2 && buf[..2] != SYNC {
            return Err(PacketError::BadSync(buf[0], buf[1]));
        }
        if buf.len() < 4 {
            return Ok(None);
        }
        let len = usize::from(u16::from_le_bytes([buf[2], buf[3]]));
        if !(MIN_PACKET_LEN..=MAX_PACKET_LEN).contains(&len) {
            return Err(PacketError::BadLength(len));
        }
        if buf.len() < len {
            return Ok(None);
        }
        let command = u16::from_le_bytes([buf[4], buf[5]]);
        let computed = checksum(&buf[..len - 2]);
        let got = u16::from_be_bytes([buf[len - 2], buf[len - 1]]);
        if got != computed {
            return Err(PacketError::BadChecksum {
                command,
                got,
                computed,
            });
        }
        let payload = buf[HEADER_LEN..len - 2].to_vec();
        Ok(Some((Packet { command, payload }, len)))
    }

    /// Decodes a buffer that must hold exactly one whole packet (a short one is
    /// [`PacketError::Truncated`]).
    pub fn decode_exact(buf: &[u8]) -> Result<Packet, PacketError> {
        match Self::decode(buf)? {
            Some((packet, used)) if used == buf.len() => Ok(packet),
            Some((_, used)) => Err(PacketError::BadLength(used)),
            None => Err(PacketError::Truncated {
                have: buf.len(),
                need: if buf.len() >= 4 {
                    usize::from(u16::from_le_bytes([buf[2], buf[3]]))
                } else {
                    MIN_PACKET_LEN
                },
            }),
        }
    }
}

/// Formats `x` as C's `printf("%g", x)` (6 significant digits, trailing zeros dropped,
/// exponent form below 1e-4 and from 1e6), with `INF`/`-INF` for infinities and `NAN` for NaN.
pub fn format_g(x: f64) -> String {
    if x.is_nan() {
        return "NAN".into();
    }
    if x.is_infinite() {
        return if x > 0.0 { "INF".into() } else { "-INF".into() };
    }
    if x == 0.0 {
        return if x.is_sign_negative() {
            "-0".into()
        } else {
            "0".into()
        };
    }
    const P: i32 = 6;
    // The exponent after rounding to P significant digits.
    let sci = format!("{:.*e}", (P - 1) as usize, x);
    let (mantissa, exp) = sci.split_once('e').expect("exponent form");
    let exp: i32 = exp.parse().expect("exponent");
    if !(-4..P).contains(&exp) {
        let mantissa = strip_zeros(mantissa);
        let sign = if exp < 0 { '-' } else { '+' };
        format!("{mantissa}e{sign}{:02}", exp.abs())
    } else {
        strip_zeros(&format!("{:.*}", (P - 1 - exp) as usize, x)).to_owned()
    }
}

/// `s` without trailing fractional zeros (and without a trailing point).
fn strip_zeros(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}

/// Builds a payload field by field.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PayloadWriter {
    buf: Vec<u8>,
}

impl PayloadWriter {
    /// An empty payload.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends a `ubyte`.
    pub fn u8(mut self, v: u8) -> Self {
        self.buf.push(v);
        self
    }

    /// Appends a `byte` (signed).
    pub fn i8(self, v: i8) -> Self {
        self.u8(v as u8)
    }

    /// Appends a `ubyte2` (little-endian).
    pub fn u16(mut self, v: u16) -> Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// Appends a `byte2` (signed, little-endian).
    pub fn i16(mut self, v: i16) -> Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// Appends a `ubyte4` (little-endian).
    pub fn u32(mut self, v: u32) -> Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// Appends a `byte4` (signed, little-endian).
    pub fn i32(mut self, v: i32) -> Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// Appends a NUL-terminated string (a NUL inside `s` would end it early: it is dropped).
    pub fn str(mut self, s: &str) -> Self {
        self.buf.extend(s.bytes().filter(|&b| b != 0));
        self.buf.push(0);
        self
    }

    /// Appends raw bytes (no terminator).
    pub fn bytes(mut self, b: &[u8]) -> Self {
        self.buf.extend_from_slice(b);
        self
    }

    /// Appends a double as a NUL-terminated `%g` string.
    pub fn double(self, v: f64) -> Self {
        let s = format_g(v);
        self.str(&s)
    }

    /// The payload.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

/// Reads a payload field by field; every read past the end is a [`PacketError`].
#[derive(Debug, Clone)]
pub struct PayloadReader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> PayloadReader<'a> {
    /// A reader at the start of `payload`.
    pub fn new(payload: &'a [u8]) -> Self {
        Self {
            buf: payload,
            pos: 0,
        }
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    /// The next `n` raw bytes.
    pub fn bytes(&mut self, n: usize, field: &'static str) -> Result<&'a [u8], PacketError> {
        if self.remaining() < n {
            return Err(PacketError::ShortPayload { field });
        }
        let out = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }

    /// A `ubyte`.
    pub fn u8(&mut self, field: &'static str) -> Result<u8, PacketError> {
        Ok(self.bytes(1, field)?[0])
    }

    /// A `byte` (signed).
    pub fn i8(&mut self, field: &'static str) -> Result<i8, PacketError> {
        Ok(self.u8(field)? as i8)
    }

    /// A `ubyte2`.
    pub fn u16(&mut self, field: &'static str) -> Result<u16, PacketError> {
        let b = self.bytes(2, field)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    /// A `byte2`.
    pub fn i16(&mut self, field: &'static str) -> Result<i16, PacketError> {
        Ok(self.u16(field)? as i16)
    }

    /// A `ubyte4`.
    pub fn u32(&mut self, field: &'static str) -> Result<u32, PacketError> {
        let b = self.bytes(4, field)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// A `byte4`.
    pub fn i32(&mut self, field: &'static str) -> Result<i32, PacketError> {
        Ok(self.u32(field)? as i32)
    }

    /// A NUL-terminated string (bytes that are not UTF-8 are replaced).
    pub fn str(&mut self, field: &'static str) -> Result<String, PacketError> {
        let rest = &self.buf[self.pos..];
        let Some(end) = rest.iter().position(|&b| b == 0) else {
            return Err(PacketError::BadField {
                field,
                detail: "string without a terminating NUL".into(),
            });
        };
        self.pos += end + 1;
        Ok(String::from_utf8_lossy(&rest[..end]).into_owned())
    }

    /// A double sent as a `%g` string (`INF`, `-INF` accepted).
    pub fn double(&mut self, field: &'static str) -> Result<f64, PacketError> {
        let s = self.str(field)?;
        s.trim().parse::<f64>().map_err(|e| PacketError::BadField {
            field,
            detail: format!("'{s}' is not a number: {e}"),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(bytes: &[u8]) -> String {
        bytes
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect::<Vec<_>>()
            .join(" ")
    }

    #[test]
    fn tcp_only_is_the_worked_example() {
        let bytes = Packet::empty(5).encode().unwrap();
        assert_eq!(hex(&bytes), "0f 0c 08 00 05 00 00 05");
        let (p, used) = Packet::decode(&bytes).unwrap().unwrap();
        assert_eq!((p, used), (Packet::empty(5), 8));
    }

    #[test]
    fn ratio_drive_300_is_the_worked_example_with_the_odd_byte_quirk() {
        let payload = PayloadWriter::new()
            .double(50.0)
            .double(0.0)
            .double(100.0)
            .double(0.0)
            .finish();
        assert_eq!(
            payload.len(),
            11,
            "odd payload: the checksum skips its last byte"
        );
        let bytes = Packet::new(300, payload.clone()).encode().unwrap();
        assert_eq!(
            hex(&bytes),
            "0f 0c 13 00 2c 01 35 30 00 30 00 31 30 30 00 30 00 c2 a1"
        );
        // The quirk: the last payload byte is not covered, the length's low byte neither.
        let mut other = bytes.clone();
        other[16] = 0x7f;
        other[2] = 0x55;
        assert_eq!(checksum(&other[..17]), 0xc2a1);
        let p = Packet::decode_exact(&bytes).unwrap();
        let mut r = PayloadReader::new(&p.payload);
        let values: Vec<f64> = (0..4).map(|_| r.double("v").unwrap()).collect();
        assert_eq!(values, vec![50.0, 0.0, 100.0, 0.0]);
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn bad_checksum_sync_length_and_truncation_are_typed_errors() {
        let mut bytes = Packet::new(300, vec![1, 2, 3, 4]).encode().unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0xff;
        assert!(matches!(
            Packet::decode(&bytes),
            Err(PacketError::BadChecksum { command: 300, .. })
        ));
        assert_eq!(
            Packet::decode(&[0x0f, 0x0d, 8, 0]),
            Err(PacketError::BadSync(0x0f, 0x0d))
        );
        assert_eq!(
            Packet::decode(&[0x0f, 0x0c, 3, 0]),
            Err(PacketError::BadLength(3))
        );
        let good = Packet::new(7, vec![9; 10]).encode().unwrap();
        assert_eq!(Packet::decode(&good[..good.len() - 1]), Ok(None));
        assert_eq!(
            Packet::decode_exact(&good[..good.len() - 1]),
            Err(PacketError::Truncated { have: 17, need: 18 })
        );
        assert!(Packet::new(1, vec![0; MAX_PACKET_LEN]).encode().is_err());
    }

    #[test]
    fn percent_g_matches_c() {
        let cases = [
            (50.0, "50"),
            (0.0, "0"),
            (100.0, "100"),
            (-12.5, "-12.5"),
            (1.0 / 3.0, "0.333333"),
            (123456.0, "123456"),
            (1234567.0, "1.23457e+06"),
            (0.0001, "0.0001"),
            (0.00001234, "1.234e-05"),
            (99.99999, "100"),
            (f64::INFINITY, "INF"),
            (f64::NEG_INFINITY, "-INF"),
        ];
        for (x, s) in cases {
            assert_eq!(format_g(x), s, "{x}");
        }
        let p = PayloadWriter::new().double(f64::NEG_INFINITY).finish();
        assert_eq!(PayloadReader::new(&p).double("x"), Ok(f64::NEG_INFINITY));
    }

    #[test]
    fn payload_fields_round_trip_and_short_reads_fail() {
        let p = PayloadWriter::new()
            .u8(1)
            .i8(-2)
            .u16(0x1234)
            .i16(-300)
            .u32(0xdeadbeef)
            .i32(-70000)
            .str("alpha")
            .finish();
        let mut r = PayloadReader::new(&p);
        assert_eq!(r.u8("a"), Ok(1));
        assert_eq!(r.i8("b"), Ok(-2));
        assert_eq!(r.u16("c"), Ok(0x1234));
        assert_eq!(r.i16("d"), Ok(-300));
        assert_eq!(r.u32("e"), Ok(0xdeadbeef));
        assert_eq!(r.i32("f"), Ok(-70000));
        assert_eq!(r.str("g").as_deref(), Ok("alpha"));
        assert_eq!(r.u8("h"), Err(PacketError::ShortPayload { field: "h" }));
        assert!(matches!(
            PayloadReader::new(b"abc").str("s"),
            Err(PacketError::BadField { .. })
        ));
        assert!(PayloadReader::new(b"x1\0").double("d").is_err());
    }
}

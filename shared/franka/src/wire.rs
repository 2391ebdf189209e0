//! Byte-level helpers shared by every codec: packed little-endian fields written at fixed
//! offsets, and the typed decoding error.

/// Why bytes could not be decoded into a protocol message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ProtocolError {
    /// A fixed-size message (a UDP datagram, or a TCP message whose size is fixed) had the
    /// wrong number of bytes ("incorrect object size" in libfranka).
    #[error("{message}: incorrect object size: expected {expected} bytes, got {got}")]
    WrongSize {
        /// The message.
        message: &'static str,
        /// Its size, bytes.
        expected: usize,
        /// The bytes received.
        got: usize,
    },
    /// The bytes end before a field does.
    #[error("{message}: truncated at field `{field}`: needs {needed} bytes, got {got}")]
    Truncated {
        /// The message.
        message: &'static str,
        /// The first field that does not fit.
        field: &'static str,
        /// Bytes the message needs up to the end of that field.
        needed: usize,
        /// Bytes available.
        got: usize,
    },
    /// The header names a command number the protocol does not have.
    #[error("{message}: unknown command number {command}")]
    UnknownCommand {
        /// The message (which protocol's header).
        message: &'static str,
        /// The number received.
        command: u32,
    },
    /// A response arrived for another command than the one awaited.
    #[error("{message}: expected command {expected}, got command {got}")]
    UnexpectedCommand {
        /// The message awaited.
        message: &'static str,
        /// Command number awaited.
        expected: u32,
        /// Command number received.
        got: u32,
    },
    /// A field holds a value outside its enum.
    #[error("{message}: field `{field}` has unknown value {value}")]
    UnknownValue {
        /// The message.
        message: &'static str,
        /// The field.
        field: &'static str,
        /// The value received.
        value: u32,
    },
    /// The peer speaks another protocol version.
    #[error("{message}: incompatible version: ours is {ours}, the peer's is {theirs}")]
    IncompatibleVersion {
        /// The message that carried the version.
        message: &'static str,
        /// The version this crate speaks.
        ours: u16,
        /// The peer's version.
        theirs: u16,
    },
    /// A value to be sent is NaN or infinite (never sent).
    #[error("{message}: field `{field}` is not finite")]
    NotFinite {
        /// The message.
        message: &'static str,
        /// The field.
        field: &'static str,
    },
}

/// A value with a fixed packed little-endian layout.
pub trait Field: Sized {
    /// Encoded size, bytes.
    const SIZE: usize;
    /// Writes the value into `out[..SIZE]`.
    fn put(&self, out: &mut [u8]);
    /// Reads the value from `bytes[..SIZE]`.
    fn get(bytes: &[u8]) -> Self;
}

macro_rules! int_field {
    ($($t:ty),*) => {$(
        impl Field for $t {
            const SIZE: usize = std::mem::size_of::<$t>();
            fn put(&self, out: &mut [u8]) {
                out[..Self::SIZE].copy_from_slice(&self.to_le_bytes());
            }
            fn get(bytes: &[u8]) -> Self {
                let mut b = [0u8; std::mem::size_of::<$t>()];
                b.copy_from_slice(&bytes[..Self::SIZE]);
                <$t>::from_le_bytes(b)
            }
        }
    )*};
}
int_field!(u8, u16, u32, u64, f64);

impl Field for bool {
    const SIZE: usize = 1;
    fn put(&self, out: &mut [u8]) {
        out[0] = u8::from(*self);
    }
    /// Any non-zero byte is `true` (as a C++ `bool` copied byte-wise).
    fn get(bytes: &[u8]) -> Self {
        bytes[0] != 0
    }
}

impl<T: Field + Copy + Default, const N: usize> Field for [T; N] {
    const SIZE: usize = T::SIZE * N;
    fn put(&self, out: &mut [u8]) {
        for (i, v) in self.iter().enumerate() {
            v.put(&mut out[i * T::SIZE..]);
        }
    }
    fn get(bytes: &[u8]) -> Self {
        let mut a = [T::default(); N];
        for (i, v) in a.iter_mut().enumerate() {
            *v = T::get(&bytes[i * T::SIZE..]);
        }
        a
    }
}

/// A sequential reader over a message's bytes that names the field that does not fit.
pub(crate) struct Reader<'a> {
    message: &'static str,
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    /// A reader over `bytes` of message `message`.
    pub(crate) fn new(message: &'static str, bytes: &'a [u8]) -> Self {
        Self {
            message,
            bytes,
            at: 0,
        }
    }

    /// The next field `field`.
    pub(crate) fn read<T: Field>(&mut self, field: &'static str) -> Result<T, ProtocolError> {
        let end = self.at + T::SIZE;
        if end > self.bytes.len() {
            return Err(ProtocolError::Truncated {
                message: self.message,
                field,
                needed: end,
                got: self.bytes.len(),
            });
        }
        let v = T::get(&self.bytes[self.at..]);
        self.at = end;
        Ok(v)
    }

    /// Errors unless every byte was read.
    pub(crate) fn finish(self) -> Result<(), ProtocolError> {
        if self.at == self.bytes.len() {
            Ok(())
        } else {
            Err(ProtocolError::WrongSize {
                message: self.message,
                expected: self.at,
                got: self.bytes.len(),
            })
        }
    }
}

/// A sequential writer of a message's bytes.
#[derive(Default)]
pub(crate) struct Writer {
    pub(crate) bytes: Vec<u8>,
}

impl Writer {
    /// Appends `value`.
    pub(crate) fn write<T: Field>(&mut self, value: T) -> &mut Self {
        let at = self.bytes.len();
        self.bytes.resize(at + T::SIZE, 0);
        value.put(&mut self.bytes[at..]);
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_are_packed_little_endian() {
        let mut w = Writer::default();
        w.write(0x0102u16)
            .write(0x0304_0506u32)
            .write(true)
            .write(1.0f64)
            .write([7u8, 8]);
        assert_eq!(
            w.bytes,
            [
                0x02, 0x01, 0x06, 0x05, 0x04, 0x03, 1, 0, 0, 0, 0, 0, 0, 0xf0, 0x3f, 7, 8
            ]
        );
        let mut r = Reader::new("m", &w.bytes);
        assert_eq!(r.read::<u16>("a"), Ok(0x0102));
        assert_eq!(r.read::<u32>("b"), Ok(0x0304_0506));
        assert_eq!(r.read::<bool>("c"), Ok(true));
        assert_eq!(r.read::<f64>("d"), Ok(1.0));
        assert_eq!(r.read::<[u8; 2]>("e"), Ok([7, 8]));
        assert_eq!(
            r.read::<u8>("f"),
            Err(ProtocolError::Truncated {
                message: "m",
                field: "f",
                needed: 18,
                got: 17
            })
        );
    }
}

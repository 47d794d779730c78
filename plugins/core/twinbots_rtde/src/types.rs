//! RTDE's data types and values: big-endian, packed without padding (RTDE guide, "Data types").

use crate::RtdeError;

/// A variable's type as the guide names it in recipes (`VECTOR6D`, `INT32`, …).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DataType {
    Bool,
    Uint8,
    Uint32,
    Uint64,
    Int32,
    Double,
    Vector3d,
    Vector6d,
    Vector6Int32,
    Vector6Uint32,
}

impl DataType {
    pub const ALL: [DataType; 10] = [
        DataType::Bool,
        DataType::Uint8,
        DataType::Uint32,
        DataType::Uint64,
        DataType::Int32,
        DataType::Double,
        DataType::Vector3d,
        DataType::Vector6d,
        DataType::Vector6Int32,
        DataType::Vector6Uint32,
    ];

    /// The name in a recipe reply.
    pub fn name(self) -> &'static str {
        match self {
            DataType::Bool => "BOOL",
            DataType::Uint8 => "UINT8",
            DataType::Uint32 => "UINT32",
            DataType::Uint64 => "UINT64",
            DataType::Int32 => "INT32",
            DataType::Double => "DOUBLE",
            DataType::Vector3d => "VECTOR3D",
            DataType::Vector6d => "VECTOR6D",
            DataType::Vector6Int32 => "VECTOR6INT32",
            DataType::Vector6Uint32 => "VECTOR6UINT32",
        }
    }

    /// The type of a recipe reply's name; `None` for the guide's markers (`NOT_FOUND`, `IN_USE`)
    /// and anything else.
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Bytes on the wire.
    pub fn size(self) -> usize {
        match self {
            DataType::Bool | DataType::Uint8 => 1,
            DataType::Uint32 | DataType::Int32 => 4,
            DataType::Uint64 | DataType::Double => 8,
            DataType::Vector3d => 24,
            DataType::Vector6d => 48,
            DataType::Vector6Int32 | DataType::Vector6Uint32 => 24,
        }
    }

    /// The value a variable holds before anything set it.
    pub fn zero(self) -> Value {
        match self {
            DataType::Bool => Value::Bool(false),
            DataType::Uint8 => Value::Uint8(0),
            DataType::Uint32 => Value::Uint32(0),
            DataType::Uint64 => Value::Uint64(0),
            DataType::Int32 => Value::Int32(0),
            DataType::Double => Value::Double(0.0),
            DataType::Vector3d => Value::Vector3d([0.0; 3]),
            DataType::Vector6d => Value::Vector6d([0.0; 6]),
            DataType::Vector6Int32 => Value::Vector6Int32([0; 6]),
            DataType::Vector6Uint32 => Value::Vector6Uint32([0; 6]),
        }
    }
}

/// One variable's value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    Bool(bool),
    Uint8(u8),
    Uint32(u32),
    Uint64(u64),
    Int32(i32),
    Double(f64),
    Vector3d([f64; 3]),
    Vector6d([f64; 6]),
    Vector6Int32([i32; 6]),
    Vector6Uint32([u32; 6]),
}

impl Value {
    pub fn data_type(&self) -> DataType {
        match self {
            Value::Bool(_) => DataType::Bool,
            Value::Uint8(_) => DataType::Uint8,
            Value::Uint32(_) => DataType::Uint32,
            Value::Uint64(_) => DataType::Uint64,
            Value::Int32(_) => DataType::Int32,
            Value::Double(_) => DataType::Double,
            Value::Vector3d(_) => DataType::Vector3d,
            Value::Vector6d(_) => DataType::Vector6d,
            Value::Vector6Int32(_) => DataType::Vector6Int32,
            Value::Vector6Uint32(_) => DataType::Vector6Uint32,
        }
    }

    /// Appends the value's bytes (big-endian).
    pub fn encode(&self, out: &mut Vec<u8>) {
        match self {
            Value::Bool(b) => out.push(*b as u8),
            Value::Uint8(v) => out.push(*v),
            Value::Uint32(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Uint64(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Int32(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Double(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Vector3d(v) => v.iter().for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6d(v) => v.iter().for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Int32(v) => v.iter().for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Uint32(v) => v.iter().for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
        }
    }

    /// Reads a value of type `t` from the front of `bytes`; returns it and the bytes after it.
    pub fn decode(t: DataType, bytes: &[u8]) -> Result<(Value, &[u8]), RtdeError> {
        if bytes.len() < t.size() {
            return Err(RtdeError::Malformed(format!(
                "{} needs {} bytes, {} left in the package",
                t.name(),
                t.size(),
                bytes.len()
            )));
        }
        let (head, rest) = bytes.split_at(t.size());
        let f64s = |n: usize| -> Vec<f64> {
            (0..n).map(|i| f64::from_be_bytes(head[8 * i..8 * i + 8].try_into().unwrap())).collect()
        };
        let u32_at = |i: usize| u32::from_be_bytes(head[4 * i..4 * i + 4].try_into().unwrap());
        let u32s = || -> [u32; 6] { std::array::from_fn(u32_at) };
        let value = match t {
            DataType::Bool => match head[0] {
                0 => Value::Bool(false),
                1 => Value::Bool(true),
                b => return Err(RtdeError::Malformed(format!("BOOL byte {b} is neither 0 nor 1"))),
            },
            DataType::Uint8 => Value::Uint8(head[0]),
            DataType::Uint32 => Value::Uint32(u32_at(0)),
            DataType::Int32 => Value::Int32(u32_at(0) as i32),
            DataType::Uint64 => Value::Uint64(u64::from_be_bytes(head.try_into().unwrap())),
            DataType::Double => Value::Double(f64s(1)[0]),
            DataType::Vector3d => Value::Vector3d(f64s(3).try_into().unwrap()),
            DataType::Vector6d => Value::Vector6d(f64s(6).try_into().unwrap()),
            DataType::Vector6Int32 => Value::Vector6Int32(u32s().map(|v| v as i32)),
            DataType::Vector6Uint32 => Value::Vector6Uint32(u32s()),
        };
        Ok((value, rest))
    }

    /// Values of `types` packed in order, filling `bytes` exactly (a recipe's data package).
    pub fn decode_all(types: impl IntoIterator<Item = DataType>, mut bytes: &[u8]) -> Result<Vec<Value>, RtdeError> {
        let mut values = Vec::new();
        for t in types {
            let (value, rest) = Value::decode(t, bytes)?;
            values.push(value);
            bytes = rest;
        }
        if !bytes.is_empty() {
            return Err(RtdeError::Malformed(format!("{} bytes after the recipe's last value", bytes.len())));
        }
        Ok(values)
    }

    /// Six doubles (`VECTOR6D`, `VECTOR6INT32`, `VECTOR6UINT32`), else `None`.
    pub fn as_vector6(&self) -> Option<[f64; 6]> {
        match *self {
            Value::Vector6d(v) => Some(v),
            Value::Vector6Int32(v) => Some(v.map(f64::from)),
            Value::Vector6Uint32(v) => Some(v.map(f64::from)),
            _ => None,
        }
    }

    /// A double's value (`DOUBLE`), else `None`.
    pub fn as_f64(&self) -> Option<f64> {
        if let Value::Double(v) = self { Some(*v) } else { None }
    }

    /// An integer's value (`INT32`, `UINT8`, `UINT32`, `UINT64` within i64, `BOOL` as 0/1).
    pub fn as_i64(&self) -> Option<i64> {
        match *self {
            Value::Bool(b) => Some(b as i64),
            Value::Uint8(v) => Some(v as i64),
            Value::Uint32(v) => Some(v as i64),
            Value::Int32(v) => Some(v as i64),
            Value::Uint64(v) => i64::try_from(v).ok(),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_type_round_trips_through_its_bytes() {
        let values = [
            Value::Bool(true),
            Value::Uint8(200),
            Value::Uint32(4_000_000_000),
            Value::Uint64(1 << 40),
            Value::Int32(-7),
            Value::Double(-1.25),
            Value::Vector3d([1.0, -2.0, 3.5]),
            Value::Vector6d([0.1, 0.2, 0.3, 0.4, 0.5, 0.6]),
            Value::Vector6Int32([-1, 2, -3, 4, -5, 6]),
            Value::Vector6Uint32([1, 2, 3, 4, 5, u32::MAX]),
        ];
        for v in values {
            let mut bytes = Vec::new();
            v.encode(&mut bytes);
            assert_eq!(bytes.len(), v.data_type().size());
            let (back, rest) = Value::decode(v.data_type(), &bytes).unwrap();
            assert_eq!(back, v);
            assert!(rest.is_empty());
            assert_eq!(DataType::parse(v.data_type().name()), Some(v.data_type()));
        }
    }

    #[test]
    fn a_short_or_bad_value_is_an_error() {
        assert!(matches!(Value::decode(DataType::Vector6d, &[0; 47]), Err(RtdeError::Malformed(_))));
        assert!(matches!(Value::decode(DataType::Bool, &[2]), Err(RtdeError::Malformed(_))));
        // Big-endian, as the guide says.
        assert_eq!(Value::decode(DataType::Int32, &[0, 0, 1, 0]).unwrap().0, Value::Int32(256));
    }
}

//! The schema hash.

use super::*;

/// The pinned hash: a change of any message type changes SCHEMA_HASH and
/// fails this test, a reminder to update PROTOCOL.md (and, if a meaning
/// changed without a type change, PROTOCOL_VERSION).
#[test]
fn schema_hash_is_pinned() {
    assert_eq!(
        SCHEMA_HASH, PINNED_SCHEMA_HASH,
        "the wire schema changed: SCHEMA_HASH is now {SCHEMA_HASH:#018x}; update \
         PINNED_SCHEMA_HASH here and the value in shared/PROTOCOL.md"
    );
}

const PINNED_SCHEMA_HASH: u64 = 0x1066_41f0_5c72_6c19;

fn hash_of<T: Schema + ?Sized>() -> u64 {
    u64::from_le_bytes(hash_ty_path::<T>(WIRE_CONVENTIONS))
}

#[test]
fn schema_hash_changes_with_any_type_change() {
    // Variants of a message, each one change away from `Base`.
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Base {
        A { x: u16, y: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Wider {
        A { x: u32, y: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Signed {
        A { x: i16, y: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Swapped {
        A { y: i32, x: u16 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Renamed {
        A { x: u16, z: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum ExtraField {
        A { x: u16, y: i32, z: bool },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum ExtraVariant {
        A { x: u16, y: i32 },
        B,
        C,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Reordered {
        B,
        A { x: u16, y: i32 },
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Optional {
        A { x: Option<u16>, y: i32 },
        B,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    struct Inner {
        v: u8,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    struct InnerChanged {
        v: u16,
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum Nested {
        A { x: u16, y: i32 },
        B(Inner),
    }
    #[derive(Schema)]
    #[allow(dead_code)]
    enum NestedChanged {
        A { x: u16, y: i32 },
        B(InnerChanged),
    }
    let hashes = [
        hash_of::<Base>(),
        hash_of::<Wider>(),
        hash_of::<Signed>(),
        hash_of::<Swapped>(),
        hash_of::<Renamed>(),
        hash_of::<ExtraField>(),
        hash_of::<ExtraVariant>(),
        hash_of::<Reordered>(),
        hash_of::<Optional>(),
        hash_of::<Nested>(),
        hash_of::<NestedChanged>(),
    ];
    for i in 0..hashes.len() {
        for j in 0..i {
            assert_ne!(hashes[i], hashes[j], "variants {i} and {j} hash alike");
        }
    }
}

#[test]
fn schema_covers_every_message_and_config_type() {
    // The hashed schema is derived from the message types themselves: every
    // variant of both enums is in it, with ConfigError's variants nested.
    let DataModelType::Enum(host) = HostMessage::SCHEMA.ty else {
        panic!("HostMessage is an enum")
    };
    assert_eq!(host.len(), 12);
    assert_eq!(host[0].name, "Hello");
    let DataModelType::Enum(device) = DeviceMessage::SCHEMA.ty else {
        panic!("DeviceMessage is an enum")
    };
    assert_eq!(device.len(), 10);
    assert_eq!(device[0].name, "HelloReply");
    let DataModelType::Enum(config_errors) = ConfigFault::SCHEMA.ty else {
        panic!()
    };
    assert!(config_errors.iter().any(|v| v.name == "MemoryBudget"));
    // The limits and conventions are part of the hash too.
    assert_ne!(
        SCHEMA_HASH,
        hash_of::<(HostMessage<'static>, DeviceMessage<'static>)>()
    );
}

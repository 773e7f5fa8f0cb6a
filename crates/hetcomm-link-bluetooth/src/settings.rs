//! The settings half of the `bluetooth` kind ([`KindSpec`], implemented by
//! [`BluetoothFactory`](crate::factory::BluetoothFactory)): its keys, how they are read from a
//! fleet file's transport table, what the table check needs of them (every system a pair
//! names has an address), and the settings of the legacy table's `B`.

use std::collections::BTreeMap;

use hetcomm_config::{
    Addresses, BdAddr, KindSpec, LegacyFiles, RegisteredSettings, SettingsReader, TransportKind,
};
use hetcomm_core::SystemId;

use crate::factory::BluetoothFactory;

/// Settings of a `bluetooth` transport.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BluetoothSettings {
    /// RFCOMM channel (1–30).
    pub channel: u8,
    /// Each system's adapter address.
    pub addresses: BTreeMap<SystemId, BdAddr>,
    /// The file the addresses were read from (`addresses_file`, or the thesis's address file
    /// of a legacy table's `B`), as errors name it; None for `addresses = { … }`.
    pub addresses_file: Option<String>,
}

/// Keys of `bluetooth` transports besides the ones every transport has.
const KEYS: [&str; 3] = ["channel", "addresses", "addresses_file"];

/// The channel of a transport that names none, and of the legacy `B`.
const DEFAULT_CHANNEL: u8 = 1;

impl KindSpec for BluetoothFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Bluetooth
    }

    fn keys(&self) -> &[&'static str] {
        &KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        let channel = s
            .int_in("channel", 1, 30, "RFCOMM channels are 1 to 30")
            .map_or(DEFAULT_CHANNEL, |c| {
                u8::try_from(c).unwrap_or(DEFAULT_CHANNEL)
            });
        let (addresses, addresses_file) = match (s.has("addresses"), s.has("addresses_file")) {
            (true, true) => {
                let message = format!(
                    "transport `{}` has both `addresses` and `addresses_file`",
                    s.transport()
                );
                s.error("addresses_file", message, "keep one of them");
                return None;
            }
            (true, false) => (s.bluetooth_addresses("addresses")?, None),
            (false, true) => {
                let (addresses, file) = s.bluetooth_address_file("addresses_file")?;
                (addresses, Some(file))
            }
            (false, false) => {
                s.missing(
                    "addresses",
                    "add `addresses = { Alpha = \"68:A3:C4:4A:B3:BA\", … }`, or `addresses_file = \"bt.txt\"` in the Table 3 format",
                );
                return None;
            }
        };
        Some(RegisteredSettings::new(BluetoothSettings {
            channel,
            addresses,
            addresses_file,
        }))
    }

    fn addresses(&self, settings: &RegisteredSettings) -> Option<Addresses> {
        let bt: &BluetoothSettings = settings.downcast_ref()?;
        Some(Addresses {
            systems: bt.addresses.keys().copied().collect(),
            what: "Bluetooth address",
            help: match &bt.addresses_file {
                Some(file) => format!("add a line `{{id}} XX:XX:XX:XX:XX:XX` to {file}"),
                None => "add `{system} = \"XX:XX:XX:XX:XX:XX\"` to `addresses` of transport \
                         `{transport}`"
                    .to_string(),
            },
        })
    }

    fn implicit(&self, legacy: &LegacyFiles<'_>) -> Option<RegisteredSettings> {
        let (addresses, file) = legacy.bluetooth?;
        Some(RegisteredSettings::new(BluetoothSettings {
            channel: DEFAULT_CHANNEL,
            addresses: addresses.clone(),
            addresses_file: Some(file.to_string()),
        }))
    }
}

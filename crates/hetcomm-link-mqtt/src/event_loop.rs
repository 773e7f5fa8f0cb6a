//! The link's thread: runs the MQTT client's event loop, hands received frames to the sink,
//! follows presence, and reconnects (resubscribing and announcing itself again) when the
//! broker goes away.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_link::{LinkEvent, Peer};
use rumqttc::v5::mqttbytes::v5::{
    ConnAck, DisconnectReasonCode, Filter, LastWill, Packet, PubAckReason, Publish,
    SubscribeReasonCode,
};
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{Client, Connection, ConnectionError, Event, MqttOptions, StateError};
use rumqttc::{Outgoing, TlsConfiguration, Transport};

use crate::presence::{Announced, PresenceEvent};
use crate::settings::{Broker, MqttSettings, Qos};
use crate::{MqttOpenError, Shared, Topics, IN_EVENT_LOOP, MAX_FRAME};

/// The client's options for each broker, in `brokers` order.
pub(crate) fn options(
    s: &MqttSettings,
    fleet: &str,
    name: &str,
    topics: &Topics,
) -> Result<Vec<MqttOptions>, MqttOpenError> {
    let client_id = format!("{}{fleet}-{name}", s.client_id_prefix).replace('/', "-");
    let will = LastWill::new(
        topics.own_presence.clone(),
        Announced::Lost.payload(),
        QoS::AtLeastOnce,
        true,
        None,
    );
    connect_options(s, &client_id, Some(will))
}

/// The options of a client `client_id` with last will `will` for each broker of `s`, in
/// `brokers` order: keep-alive, session, credentials, TLS, no Nagle.
pub(crate) fn connect_options(
    s: &MqttSettings,
    client_id: &str,
    will: Option<LastWill>,
) -> Result<Vec<MqttOptions>, MqttOpenError> {
    let tls = match s.tls() {
        true => Some(crate::tls::client_config(s).map_err(MqttOpenError::Setting)?),
        false => None,
    };
    Ok(s.brokers
        .iter()
        .map(|b| {
            let mut o = MqttOptions::new(client_id, b.host.clone(), b.port);
            o.set_keep_alive(Duration::from_secs(s.keep_alive_s as u64))
                .set_clean_start(s.clean_session)
                .set_connection_timeout((s.open_timeout_ms as u64).div_ceil(1000).max(1))
                // Frames up to the wire format's largest, with their publish around them.
                .set_max_packet_size(Some((MAX_FRAME + 64 * 1024) as u32));
            if let Some(will) = &will {
                o.set_last_will(will.clone());
            }
            if !s.clean_session {
                o.set_session_expiry_interval(Some(s.session_expiry_s));
            }
            // A frame goes out when it is published: Nagle's algorithm would hold a small
            // publish back until the previous one's TCP acknowledgement (delayed up to 40 ms
            // on Linux), and a request and its reply are each one small publish.
            let mut net = rumqttc::NetworkOptions::new();
            net.set_tcp_nodelay(true);
            o.set_network_options(net);
            if let Some(user) = &s.username {
                o.set_credentials(user.clone(), s.password.clone().unwrap_or_default());
            }
            if let Some(config) = &tls {
                o.set_transport(Transport::tls_with_config(TlsConfiguration::Rustls(
                    config.clone(),
                )));
            }
            o
        })
        .collect())
}

/// The subscriptions of a link: its own topic, the broadcasts and every system's presence,
/// none of its own publishes ("no local").
pub(crate) fn filters(shared: &Shared, qos: Qos) -> Vec<Filter> {
    let data = |topic: &str| {
        let mut f = Filter::new(topic, qos.mqtt());
        f.nolocal = true;
        f
    };
    let mut filters = vec![data(&shared.topics.own)];
    if shared.broadcast {
        filters.push(data(&shared.topics.all));
    }
    // Not its own announcements either.
    let mut presence = Filter::new(
        format!("{}+", shared.topics.presence_prefix),
        QoS::AtLeastOnce,
    );
    presence.nolocal = true;
    filters.push(presence);
    filters
}

/// A connection error in words, naming what refused what.
pub(crate) fn describe(e: &ConnectionError) -> (String, Option<String>) {
    match e {
        ConnectionError::ConnectionRefused(code) => {
            let why = format!("{code:?}");
            (format!("refused: {why}"), Some(words(&why)))
        }
        ConnectionError::MqttState(StateError::ServerDisconnect {
            reason_code,
            reason_string,
        }) => (
            format!(
                "the broker disconnected this client: {reason_code:?}{}",
                reason_string
                    .as_deref()
                    .map(|r| format!(" ({r})"))
                    .unwrap_or_default()
            ),
            None,
        ),
        other => (other.to_string(), None),
    }
}

/// `BadUserNamePassword` → `bad user name password`.
pub(crate) fn words(camel: &str) -> String {
    let mut out = String::new();
    for (i, c) in camel.chars().enumerate() {
        if c.is_uppercase() && i > 0 {
            out.push(' ');
        }
        out.extend(c.to_lowercase());
    }
    out
}

/// The first pause between connection attempts, doubled after each failure up to
/// [`RETRY_MAX`].
const RETRY_FIRST: Duration = Duration::from_millis(50);
const RETRY_MAX: Duration = Duration::from_millis(500);

/// A connection the broker closes sooner than this after it opened counts towards
/// [`TAKEN_OVER_AFTER`].
const SHORT_LIVED: Duration = Duration::from_secs(2);
/// This many short-lived connections in a row: another client uses this system's client id.
const TAKEN_OVER_AFTER: u32 = 3;

/// Runs until the link closes.
pub(crate) fn run(
    shared: Arc<Shared>,
    client: Client,
    mut connection: Connection,
    options: Vec<MqttOptions>,
    brokers: Vec<Broker>,
    filters: Vec<Filter>,
) {
    IN_EVENT_LOOP.with(|c| c.set(true));
    let mut current = 0;
    let mut pause = RETRY_FIRST;
    let mut connected_at: Option<Instant> = None;
    let mut short_lived = 0;
    loop {
        let Ok(event) = connection.recv() else { break };
        match &event {
            Ok(event) => shared.receipts.on_event(event),
            Err(_) => shared.receipts.disconnected(&connection.eventloop.pending),
        }
        match event {
            Ok(Event::Incoming(Packet::ConnAck(ack))) => {
                pause = RETRY_FIRST;
                connected_at = Some(Instant::now());
                shared.receipts.connected(ack.session_present);
                on_connack(&shared, &client, &ack, &filters);
            }
            Ok(Event::Incoming(Packet::SubAck(ack))) => {
                let refused: Vec<String> = ack
                    .return_codes
                    .iter()
                    .filter(|c| !matches!(c, SubscribeReasonCode::Success(_)))
                    .map(|c| format!("{c:?}"))
                    .collect();
                let mut conn = shared.lock();
                if refused.is_empty() {
                    conn.ready = true;
                    conn.last_error = None;
                } else {
                    conn.refused = Some(format!(
                        "the broker refused this system's subscriptions: {}",
                        refused.join(", ")
                    ));
                }
                drop(conn);
                shared.changed.notify_all();
            }
            Ok(Event::Incoming(Packet::Publish(p))) => on_publish(&shared, &p),
            Ok(Event::Incoming(Packet::PubAck(ack))) => {
                let c = &shared.counters;
                match ack.reason {
                    PubAckReason::Success => c.broker_acks.fetch_add(1, Ordering::Relaxed),
                    PubAckReason::NoMatchingSubscribers => {
                        c.no_subscribers.fetch_add(1, Ordering::Relaxed)
                    }
                    _ => {
                        c.dropped.fetch_add(1, Ordering::Relaxed);
                        c.broker_refusals.fetch_add(1, Ordering::Relaxed)
                    }
                };
            }
            Ok(Event::Outgoing(Outgoing::Disconnect)) if shared.closing.load(Ordering::SeqCst) => {
                drain(&mut connection);
                break;
            }
            Ok(_) => {}
            Err(e) => {
                let (text, refused) = describe(&e);
                // mosquitto closes a connection whose client id another client takes without
                // a DISCONNECT saying so (MQTT 5's "session taken over" where a broker sends it):
                // connections closed soon after they opened, again and again, are that.
                let short = connected_at
                    .take()
                    .is_some_and(|t| t.elapsed() < SHORT_LIVED);
                short_lived = if short { short_lived + 1 } else { 0 };
                let taken_over = short_lived >= TAKEN_OVER_AFTER
                    || matches!(
                        e,
                        ConnectionError::MqttState(StateError::ServerDisconnect {
                            reason_code: DisconnectReasonCode::SessionTakenOver,
                            ..
                        })
                    );
                let mut conn = shared.lock();
                conn.ready = false;
                conn.last_error = Some(text);
                if refused.is_some() {
                    conn.refused = refused;
                }
                if taken_over {
                    // Another client connected with this system's client id (the system
                    // opened twice): reconnecting would take it back, and the two would push
                    // each other off for ever. This link stops; sends say why.
                    conn.last_error = Some(format!(
                        "another client connected with this system's client id `{}` (the broker closed this link's connection right after it opened, {short_lived} times; is the system open in another process?); this link stopped",
                        options[current].client_id()
                    ));
                    conn.taken_over = true;
                }
                drop(conn);
                shared.changed.notify_all();
                if shared.closing.load(Ordering::SeqCst) || taken_over {
                    break;
                }
                // The next broker of the list, if there are several.
                if options.len() > 1 {
                    current = (current + 1) % options.len();
                    connection.eventloop.options = options[current].clone();
                    shared.lock().broker = brokers[current].to_string();
                    shared.receipts.set_broker(brokers[current].to_string());
                }
                std::thread::sleep(pause);
                pause = (pause * 2).min(RETRY_MAX);
            }
        }
    }
    shared.lock().ready = false;
    shared.changed.notify_all();
}

/// After the DISCONNECT: reads until the broker closes the connection (at most
/// [`DRAIN`]). Closing a socket with unread bytes in it sends a reset, and a broker that gets
/// one before it handled the DISCONNECT takes the close for a broken connection and publishes
/// the last will (`lost`) over the `offline` just published (seen with mosquitto 2.0.11).
fn drain(connection: &mut Connection) {
    let deadline = Instant::now() + DRAIN;
    while let Some(left) = deadline.checked_duration_since(Instant::now()) {
        match connection.recv_timeout(left) {
            Ok(Ok(_)) => {}
            _ => return,
        }
    }
}

/// How long [`drain`] waits for the broker to close the connection.
const DRAIN: Duration = Duration::from_millis(500);

/// A connection came up: subscribe again if the broker kept no session, and announce this
/// system online (retained). The link is ready at the SUBACK (or at once when the session
/// and its subscriptions were kept).
fn on_connack(shared: &Shared, client: &Client, ack: &ConnAck, filters: &[Filter]) {
    shared.counters.connects.fetch_add(1, Ordering::Relaxed);
    let mut conn = shared.lock();
    conn.broker_max_packet = ack.properties.as_ref().and_then(|p| p.max_packet_size);
    conn.refused = None;
    drop(conn);
    if !ack.session_present {
        shared.presence.forget_all();
        let _ = client.try_subscribe_many(filters.to_vec());
    }
    // After the subscriptions: whoever sees `online` can publish to this system. Not while
    // closing: the link's `offline` is queued already.
    if shared.closing.load(Ordering::SeqCst) {
        return;
    }
    let _ = shared.receipts.queue(QoS::AtLeastOnce, &mut None, || {
        client
            .try_publish(
                shared.topics.own_presence.clone(),
                QoS::AtLeastOnce,
                true,
                Announced::Online.payload(),
            )
            .is_ok()
    });
    if ack.session_present {
        let mut conn = shared.lock();
        conn.ready = true;
        conn.last_error = None;
        drop(conn);
        shared.changed.notify_all();
    }
}

/// A publish from the broker: a frame for this system (or a broadcast), or a presence message.
fn on_publish(shared: &Shared, p: &Publish) {
    let topic = &p.topic[..];
    let c = &shared.counters;
    if topic == shared.topics.own.as_bytes()
        || (shared.broadcast && topic == shared.topics.all.as_bytes())
    {
        // A retained message on a data topic is an old frame (or garbage) replayed to every
        // new subscriber: never a frame of this session's traffic.
        if p.retain || p.payload.is_empty() {
            c.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        c.received.fetch_add(1, Ordering::Relaxed);
        shared.sink.on_frame(&p.payload, Peer::Unknown);
        return;
    }
    let Some(name) = topic.strip_prefix(shared.topics.presence_prefix.as_bytes()) else {
        c.dropped.fetch_add(1, Ordering::Relaxed);
        return;
    };
    let Some(&id) = std::str::from_utf8(name)
        .ok()
        .and_then(|n| shared.names.get(n))
    else {
        return; // not a system of this fleet
    };
    if id == shared.local || p.payload.is_empty() {
        return; // our own announcement, or a retained message being cleared
    }
    let Some(announced) = Announced::from_payload(&p.payload) else {
        c.dropped.fetch_add(1, Ordering::Relaxed);
        return;
    };
    match shared.presence.set(id, announced, !p.retain) {
        // The router sends what waited for it now.
        Some(PresenceEvent::Joined(id)) => shared.sink.on_event(LinkEvent::PeerUp(id)),
        // The router's failover takes a pair with another transport off this one.
        Some(PresenceEvent::Left(id)) => shared.sink.on_event(LinkEvent::PeerDown(id)),
        None => {}
    }
}

//! The few ROS XML-RPC calls the link makes itself, because roslibrust does not offer them: the
//! master's `getSystemState` with its node lists (roslibrust's `SystemState` only answers "is
//! this node subscribed"), `lookupNode`, and a node's `getBusInfo`.

use std::time::Duration;

use serde_xmlrpc::Value;

/// Why an XML-RPC call failed.
#[derive(Debug)]
pub(crate) struct CallError {
    /// The HTTP status, when the server answered with an error status (roslibrust's node
    /// server answers `501 Not Implemented` to `getBusInfo`).
    pub(crate) http_status: Option<u16>,
    /// What went wrong.
    pub(crate) message: String,
}

impl std::fmt::Display for CallError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

fn failed(message: String) -> CallError {
    CallError {
        http_status: None,
        message,
    }
}

/// Calls `method` on the XML-RPC server at `uri` and returns the value of a successful ROS
/// answer (`[1, message, value]`); anything else, or no answer within `timeout`, is an error.
pub(crate) async fn call(
    http: &reqwest::Client,
    uri: &str,
    method: &str,
    args: Vec<Value>,
    timeout: Duration,
) -> Result<Value, CallError> {
    let body = serde_xmlrpc::request_to_string(method, args).map_err(|e| failed(e.to_string()))?;
    let exchange = async {
        let response = http
            .post(uri)
            .body(body)
            .send()
            .await
            .map_err(|e| failed(e.to_string()))?;
        let status = response.status();
        let text = response.text().await.map_err(|e| failed(e.to_string()))?;
        if !status.is_success() {
            return Err(CallError {
                http_status: Some(status.as_u16()),
                message: format!("{method} at {uri}: HTTP {status}"),
            });
        }
        let (code, message, value): (i32, String, Value) =
            serde_xmlrpc::response_from_str(&text)
                .map_err(|e| failed(format!("{method} at {uri}: {e}")))?;
        if code != 1 {
            return Err(failed(format!("{method} at {uri}: {message}")));
        }
        Ok(value)
    };
    tokio::time::timeout(timeout, exchange)
        .await
        .unwrap_or_else(|_| {
            Err(failed(format!(
                "{method} at {uri}: no answer within {timeout:?}"
            )))
        })
}

fn string(v: &Value) -> Option<&str> {
    match v {
        Value::String(s) => Some(s),
        _ => None,
    }
}

/// Who publishes and who subscribes, as the master's `getSystemState` lists them.
#[derive(Clone, Debug, Default)]
pub(crate) struct Graph {
    publishers: Vec<(String, Vec<String>)>,
    subscribers: Vec<(String, Vec<String>)>,
}

/// One list of a `getSystemState` answer: `[topic, [node, …]]` entries; others are skipped.
fn topic_nodes(list: Option<&Value>) -> Vec<(String, Vec<String>)> {
    let Some(Value::Array(entries)) = list else {
        return Vec::new();
    };
    entries
        .iter()
        .filter_map(|entry| {
            let Value::Array(pair) = entry else {
                return None;
            };
            let topic = string(pair.first()?)?.to_string();
            let Value::Array(nodes) = pair.get(1)? else {
                return None;
            };
            let nodes = nodes.iter().filter_map(string).map(str::to_string);
            Some((topic, nodes.collect()))
        })
        .collect()
}

fn nodes_of(list: &[(String, Vec<String>)], topic: &str) -> Vec<String> {
    let mut nodes: Vec<String> = list
        .iter()
        .filter(|(t, _)| t == topic)
        .flat_map(|(_, n)| n.iter().cloned())
        .collect();
    nodes.sort();
    nodes.dedup();
    nodes
}

impl Graph {
    /// Reads a `getSystemState` value (`[publishers, subscribers, services]`, each a list of
    /// `[topic, [node, …]]`); entries of other shapes are skipped.
    pub(crate) fn from_value(value: &Value) -> Graph {
        let Value::Array(parts) = value else {
            return Graph::default();
        };
        Graph {
            publishers: topic_nodes(parts.first()),
            subscribers: topic_nodes(parts.get(1)),
        }
    }

    /// The nodes subscribed to `topic`, sorted.
    pub(crate) fn subscribers(&self, topic: &str) -> Vec<String> {
        nodes_of(&self.subscribers, topic)
    }

    /// The nodes publishing `topic`, sorted.
    pub(crate) fn publishers(&self, topic: &str) -> Vec<String> {
        nodes_of(&self.publishers, topic)
    }
}

/// The type a node's `getPublications` answer (`[[topic, type], …]`) gives `topic`.
pub(crate) fn publication_type(publications: &Value, topic: &str) -> Option<String> {
    let Value::Array(entries) = publications else {
        return None;
    };
    entries.iter().find_map(|entry| match entry {
        Value::Array(pair) if pair.first().and_then(string) == Some(topic) => {
            pair.get(1).and_then(string).map(str::to_string)
        }
        _ => None,
    })
}

/// Whether a `getBusInfo` answer (a list of `[id, peer, direction, transport, topic,
/// connected, info]`) lists an inbound connection on `topic` from the publisher whose XML-RPC
/// URI is `publisher_uri` (rospy and roscpp name the publisher of an inbound connection by its
/// URI; a trailing `/` is ignored), with its handshake done.
pub(crate) fn bus_info_has_inbound(info: &Value, topic: &str, publisher_uri: &str) -> bool {
    inbound_connection(info, topic, publisher_uri).is_some()
}

/// The id of the connection that [`bus_info_has_inbound`] finds, if it finds one.
///
/// rospy lists a subscriber's connection as soon as it starts connecting (before the TCP
/// connection and the TCPROS handshake), always with `connected` true; its `info` text names
/// the local port only once the handshake read the publisher's header ("TCPROS connection on
/// port None to [None:None …]" before). A connection whose text says `port None` is not
/// counted: a message published before the handshake is lost.
pub(crate) fn inbound_connection(info: &Value, topic: &str, publisher_uri: &str) -> Option<i64> {
    let Value::Array(connections) = info else {
        return None;
    };
    let want = publisher_uri.trim_end_matches('/');
    connections.iter().find_map(|c| {
        let Value::Array(f) = c else {
            return None;
        };
        let peer = f.get(1).and_then(string).map(|s| s.trim_end_matches('/'));
        let direction = f.get(2).and_then(string);
        let on_topic = f.get(4).and_then(string);
        let connected = match f.get(5) {
            Some(Value::Bool(b)) => *b,
            Some(Value::Int(i)) => *i != 0,
            // Older nodes send no `connected` field: listed means connected.
            None => true,
            _ => false,
        };
        let handshaken = !f
            .get(6)
            .and_then(string)
            .is_some_and(|text| text.contains("port None"));
        let id = match f.first() {
            Some(Value::Int(i)) => i64::from(*i),
            Some(Value::Int64(i)) => *i,
            _ => -1,
        };
        (peer == Some(want)
            && direction == Some("i")
            && on_topic == Some(topic)
            && connected
            && handshaken)
            .then_some(id)
    })
}

/// How many messages a subscriber's connection `id` on `topic` has read, from its
/// `getBusStats` answer (`[publishStats, subscribeStats, serviceStats]`, subscribeStats a list
/// of `[topic, [[id, bytes, messages, drops, connected], …]]`, as rospy answers).
pub(crate) fn messages_read(stats: &Value, topic: &str, id: i64) -> Option<i64> {
    let int = |v: &Value| match v {
        Value::Int(i) => Some(i64::from(*i)),
        Value::Int64(i) => Some(*i),
        _ => None,
    };
    let Value::Array(parts) = stats else {
        return None;
    };
    let Some(Value::Array(subscribed)) = parts.get(1) else {
        return None;
    };
    subscribed.iter().find_map(|t| {
        let Value::Array(t) = t else {
            return None;
        };
        if t.first().and_then(string) != Some(topic) {
            return None;
        }
        let Some(Value::Array(connections)) = t.get(1) else {
            return None;
        };
        connections.iter().find_map(|c| {
            let Value::Array(c) = c else {
                return None;
            };
            (c.first().and_then(int) == Some(id))
                .then(|| c.get(2).and_then(int))
                .flatten()
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(x: &str) -> Value {
        Value::String(x.to_string())
    }

    #[test]
    fn graph_lists_the_subscribers_of_a_topic() {
        let state = Value::Array(vec![
            Value::Array(vec![Value::Array(vec![
                s("/a"),
                Value::Array(vec![s("/pub")]),
            ])]),
            Value::Array(vec![
                Value::Array(vec![s("/a"), Value::Array(vec![s("/z"), s("/y")])]),
                Value::Array(vec![s("/b"), Value::Array(vec![s("/x")])]),
                Value::Int(3),
            ]),
            Value::Array(vec![]),
        ]);
        let g = Graph::from_value(&state);
        assert_eq!(g.subscribers("/a"), vec!["/y", "/z"]);
        assert_eq!(g.subscribers("/b"), vec!["/x"]);
        assert!(g.subscribers("/pub").is_empty());
        assert_eq!(g.publishers("/a"), vec!["/pub"]);
        let pubs = Value::Array(vec![Value::Array(vec![s("/a"), s("std_msgs/String")])]);
        assert_eq!(
            publication_type(&pubs, "/a").as_deref(),
            Some("std_msgs/String")
        );
        assert_eq!(publication_type(&pubs, "/b"), None);
        assert!(Graph::from_value(&Value::Int(1))
            .subscribers("/a")
            .is_empty());
    }

    #[test]
    fn bus_info_matches_inbound_connections_from_the_publisher_only() {
        // As rospy answers (checked against rospy 1.15/1.16).
        let info = Value::Array(vec![Value::Array(vec![
            Value::Int(1),
            s("http://127.0.0.1:37533/"),
            s("i"),
            s("TCPROS"),
            s("/t"),
            Value::Bool(true),
            s("TCPROS connection on port 55534"),
        ])]);
        assert!(bus_info_has_inbound(&info, "/t", "http://127.0.0.1:37533"));
        assert!(bus_info_has_inbound(&info, "/t", "http://127.0.0.1:37533/"));
        assert!(!bus_info_has_inbound(&info, "/u", "http://127.0.0.1:37533"));
        assert!(!bus_info_has_inbound(&info, "/t", "http://127.0.0.1:1"));
        let outbound = Value::Array(vec![Value::Array(vec![
            Value::Int(1),
            s("http://127.0.0.1:37533/"),
            s("o"),
            s("TCPROS"),
            s("/t"),
            Value::Bool(true),
        ])]);
        assert!(!bus_info_has_inbound(
            &outbound,
            "/t",
            "http://127.0.0.1:37533"
        ));
        let down = Value::Array(vec![Value::Array(vec![
            Value::Int(1),
            s("http://127.0.0.1:37533/"),
            s("i"),
            s("TCPROS"),
            s("/t"),
            Value::Bool(false),
        ])]);
        assert!(!bus_info_has_inbound(&down, "/t", "http://127.0.0.1:37533"));
        assert!(!bus_info_has_inbound(&Value::Nil, "/t", "x"));
        // rospy before the handshake: listed, "connected", but no port yet.
        let connecting = Value::Array(vec![Value::Array(vec![
            Value::Int(3),
            s("http://127.0.0.1:37533/"),
            s("i"),
            s("TCPROS"),
            s("/t"),
            Value::Bool(true),
            s("TCPROS connection on port None to [None:None on socket None]"),
        ])]);
        assert!(!bus_info_has_inbound(
            &connecting,
            "/t",
            "http://127.0.0.1:37533"
        ));
        assert_eq!(
            inbound_connection(&info, "/t", "http://127.0.0.1:37533"),
            Some(1)
        );
    }

    #[test]
    fn bus_stats_give_the_messages_a_connection_read() {
        // rospy: [publishStats, subscribeStats, serviceStats].
        let stats = Value::Array(vec![
            Value::Array(vec![]),
            Value::Array(vec![Value::Array(vec![
                s("/t"),
                Value::Array(vec![Value::Array(vec![
                    Value::Int(4),
                    Value::Int(120),
                    Value::Int(3),
                    Value::Int(-1),
                    Value::Bool(true),
                ])]),
            ])]),
            Value::Array(vec![]),
        ]);
        assert_eq!(messages_read(&stats, "/t", 4), Some(3));
        assert_eq!(messages_read(&stats, "/t", 5), None);
        assert_eq!(messages_read(&stats, "/u", 4), None);
        assert_eq!(messages_read(&Value::Nil, "/t", 4), None);
    }
}

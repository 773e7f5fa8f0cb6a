//! ROS 2 names on DDS, as ROS 2's own middleware layers map them (so that `ros2 topic list`,
//! rclpy/rclcpp and a plain DDS program all see the same topic): ROS topic `/a/b` is DDS
//! topic `rt/a/b`, ROS type `pkg/msg/Type` is DDS type `pkg::msg::dds_::Type_`.

/// Checks and normalises a ROS 2 namespace: a leading `/`, no trailing one, tokens of
/// letters, digits and underscores that do not start with a digit. `"/"` is the root.
pub fn check_namespace(ns: &str) -> Result<String, &'static str> {
    if ns.is_empty() {
        return Err("it is empty");
    }
    let trimmed = ns.trim_matches('/');
    if trimmed.is_empty() {
        return Ok("/".to_string());
    }
    for token in trimmed.split('/') {
        check_token(token)?;
    }
    Ok(format!("/{trimmed}"))
}

/// Checks one token of a ROS 2 name.
fn check_token(token: &str) -> Result<(), &'static str> {
    if token.is_empty() {
        return Err("it has an empty part (`//`)");
    }
    if token.starts_with(|c: char| c.is_ascii_digit()) {
        return Err("a part starts with a digit");
    }
    if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err("only letters, digits, `_` and `/` are allowed");
    }
    Ok(())
}

/// Checks a fully qualified ROS 2 topic name (`/charlie/cmd_vel`).
pub fn check_topic(topic: &str) -> Result<(), &'static str> {
    if !topic.starts_with('/') {
        return Err("it must start with `/`");
    }
    if topic.len() > 1 && topic.ends_with('/') {
        return Err("it must not end with `/`");
    }
    for token in topic[1..].split('/') {
        check_token(token)?;
    }
    Ok(())
}

/// A system's topic: `<namespace>/<name>`, with characters a ROS name cannot hold (a system
/// name may have `-` or `.`) replaced by `_`.
pub fn system_topic(namespace: &str, system: &str) -> String {
    let mut name: String = system
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    if name.starts_with(|c: char| c.is_ascii_digit()) || name.is_empty() {
        name.insert(0, '_');
    }
    match namespace {
        "/" => format!("/{name}"),
        ns => format!("{ns}/{name}"),
    }
}

/// The DDS topic of ROS 2 topic `topic` (`/a/b` → `rt/a/b`).
pub fn dds_topic(topic: &str) -> String {
    format!("rt{topic}")
}

/// The DDS type name of ROS 2 message type `ros_type`, written `pkg/msg/Type` or `pkg/Type`
/// (`std_msgs/String` → `std_msgs::msg::dds_::String_`).
pub fn dds_type(ros_type: &str) -> String {
    let mut parts = ros_type.split('/');
    let pkg = parts.next().unwrap_or_default();
    let name = parts.next_back().unwrap_or_default();
    format!("{pkg}::msg::dds_::{name}_")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_ros2_conventions() {
        assert_eq!(check_namespace("hetcomm/"), Ok("/hetcomm".to_string()));
        assert_eq!(check_namespace("/"), Ok("/".to_string()));
        assert!(check_namespace("/a//b").is_err());
        assert!(check_namespace("/9lives").is_err());
        assert!(check_namespace("/a-b").is_err());
        assert_eq!(system_topic("/hetcomm", "Bravo"), "/hetcomm/Bravo");
        assert_eq!(system_topic("/", "rover-2"), "/rover_2");
        assert_eq!(system_topic("/x", "2d"), "/x/_2d");
        assert_eq!(dds_topic("/hetcomm/Bravo"), "rt/hetcomm/Bravo");
        assert_eq!(dds_type("std_msgs/String"), "std_msgs::msg::dds_::String_");
        assert_eq!(
            dds_type("geometry_msgs/msg/Twist"),
            "geometry_msgs::msg::dds_::Twist_"
        );
        assert!(check_topic("/charlie/cmd_vel").is_ok());
        assert!(check_topic("charlie").is_err());
    }
}

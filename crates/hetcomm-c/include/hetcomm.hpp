// hetcomm.hpp: header-only C++17 wrapper over the C API of hetcomm (hetcomm.h).
//
// RAII handles (Comm, Module, Ticket, BroadcastTicket; move-only except Comm and Module,
// which are cheap shared handles), errors as exceptions (hetcomm::Error, carrying the C
// status code), typed messages through msgpack-c (Debian's libmsgpack-cxx-dev) when
// <msgpack.hpp> is available, and the thesis's CommInt facade (Send, CheckForMessage,
// GetNextMessageType, GetMessage). Guide: docs/cpp.md.
//
// Why exceptions rather than expected-style results: C++17 has no std::expected; the thesis's
// API and msgpack-c (which throws msgpack::type_error on a bad payload) are exception-based;
// constructors of RAII handles cannot return a result; and what is *not* an error here is not
// an exception either: "no message yet" is an empty std::optional, a send that failed after
// it left is an Outcome, never a throw. An exception means the call could not do what it was
// asked (unknown name, X pair, full window, bad fleet file, undecodable payload).
//
// Typed messages: a struct with msgpack-c's map form of MSGPACK_DEFINE and an id,
//
//     struct Wheels {
//         double left = 0, right = 0;
//         HETCOMM_MESSAGE(1, left, right)   // = static constexpr id 1 + MSGPACK_DEFINE_MAP
//     };
//
// is written as a MessagePack map keyed by field name, byte for byte what Rust's
// #[derive(Serialize, Deserialize, Message)] #[message(id = 1)] struct Wheels { left: f64,
// right: f64 } and Python's @hetcomm.message(id=1) @dataclass class Wheels write; each reads
// the others' messages. (Plain MSGPACK_DEFINE writes an array of fields, which Rust and
// Python accept, but msgpack-c cannot read their maps back into it: use the MAP form.)
#ifndef HETCOMM_HPP
#define HETCOMM_HPP

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#if defined(__has_include)
#if __has_include(<span>) && __cplusplus > 201703L
#include <span>
#endif
#endif

#include "hetcomm.h"

#ifndef HETCOMM_NO_MSGPACK
#if defined(__has_include)
#if __has_include(<msgpack.hpp>)
#include <msgpack.hpp>
#define HETCOMM_HAS_MSGPACK 1
#endif
#endif
#endif

#ifdef HETCOMM_HAS_MSGPACK
namespace hetcomm {
namespace detail {
/// Where hetcomm::encode writes: a byte vector.
struct PayloadStream {
    std::vector<std::uint8_t>* out;
    void write(const char* p, std::size_t n) {
        out->insert(out->end(), reinterpret_cast<const std::uint8_t*>(p), reinterpret_cast<const std::uint8_t*>(p) + n);
    }
};
}  // namespace detail
}  // namespace hetcomm

namespace msgpack {
MSGPACK_API_VERSION_NAMESPACE(v1) {
// hetcomm payloads write every double as float 64 and every float as float 32 (rmp-serde and
// Python do); msgpack-c's default packer writes integral values as integers. Specialised for
// hetcomm's own stream only, so other uses of msgpack-c in the program are unchanged.
template <>
inline packer<hetcomm::detail::PayloadStream>& packer<hetcomm::detail::PayloadStream>::pack_double(double d) {
    union { double f; uint64_t i; } mem;
    mem.f = d;
    char buf[9];
    buf[0] = static_cast<char>(0xcbu);
    _msgpack_store64(&buf[1], mem.i);
    append_buffer(buf, 9);
    return *this;
}
template <>
inline packer<hetcomm::detail::PayloadStream>& packer<hetcomm::detail::PayloadStream>::pack_float(float d) {
    union { float f; uint32_t i; } mem;
    mem.f = d;
    char buf[5];
    buf[0] = static_cast<char>(0xcau);
    _msgpack_store32(&buf[1], mem.i);
    append_buffer(buf, 5);
    return *this;
}
}  // MSGPACK_API_VERSION_NAMESPACE(v1)
}  // namespace msgpack
#endif

namespace hetcomm {

#if defined(__cpp_lib_span)
/// Read-only bytes: std::span in C++20.
using Bytes = std::span<const std::uint8_t>;
#else
/// Read-only bytes (a minimal std::span<const std::uint8_t> for C++17).
class Bytes {
public:
    constexpr Bytes() noexcept = default;
    constexpr Bytes(const std::uint8_t* data, std::size_t size) noexcept : data_(data), size_(size) {}
    template <class Container,
              class = decltype(std::declval<const Container&>().data()),
              class = decltype(std::declval<const Container&>().size())>
    Bytes(const Container& c) noexcept  // NOLINT: implicit, like std::span
        : data_(reinterpret_cast<const std::uint8_t*>(c.data())), size_(c.size() * sizeof(*c.data())) {}
    constexpr const std::uint8_t* data() const noexcept { return data_; }
    constexpr std::size_t size() const noexcept { return size_; }
    constexpr bool empty() const noexcept { return size_ == 0; }
    constexpr const std::uint8_t* begin() const noexcept { return data_; }
    constexpr const std::uint8_t* end() const noexcept { return data_ + size_; }
    constexpr std::uint8_t operator[](std::size_t i) const noexcept { return data_[i]; }

private:
    const std::uint8_t* data_ = nullptr;
    std::size_t size_ = 0;
};
#endif

/// The normal send priority (0 lowest, 255 highest).
inline constexpr std::uint8_t kNormalPriority = HETCOMM_PRIORITY_NORMAL;

/// A call of the library failed: code() is the C status, what() the library's message.
class Error : public std::runtime_error {
public:
    Error(hetcomm_status code, const std::string& message) : std::runtime_error(message), code_(code) {}
    /// The C API's status code.
    hetcomm_status code() const noexcept { return code_; }

private:
    hetcomm_status code_;
};

namespace detail {
/// Throws the thread's last error for a failed status.
inline void check(hetcomm_status s) {
    if (s != HETCOMM_STATUS_OK) {
        throw Error(s, std::string(hetcomm_status_name(s)) + ": " + hetcomm_last_error());
    }
}
struct CommDeleter { void operator()(hetcomm_comm* c) const noexcept { hetcomm_comm_close(c); } };
struct ModuleDeleter { void operator()(hetcomm_module* m) const noexcept { hetcomm_module_free(m); } };
struct TicketDeleter { void operator()(hetcomm_ticket* t) const noexcept { hetcomm_ticket_free(t); } };
struct BroadcastDeleter { void operator()(hetcomm_broadcast* b) const noexcept { hetcomm_broadcast_free(b); } };
struct MessageDeleter { void operator()(hetcomm_message* m) const noexcept { hetcomm_message_free(m); } };
inline std::string_view view(const char* s) { return s ? std::string_view(s) : std::string_view(); }
}  // namespace detail

/// How a send ended.
enum class OutcomeKind { Delivered = 0, Sent = 1, Unconfirmed = 2, Failed = 3, Relayed = 4 };

/// One send's outcome: what the sender knows.
struct Outcome {
    OutcomeKind kind = OutcomeKind::Failed;
    std::uint32_t attempts = 0;
    /// Delivered sends: first transmission to acknowledgement.
    std::chrono::microseconds latency{0};
    /// Unconfirmed and failed sends: why.
    hetcomm_fail_reason reason = HETCOMM_FAIL_REASON_NONE;

    static Outcome from(const hetcomm_outcome& o) {
        return Outcome{static_cast<OutcomeKind>(o.kind), o.attempts, std::chrono::microseconds(o.latency_us), o.reason};
    }
    /// In the destination module's inbox (acknowledged).
    bool delivered() const noexcept { return kind == OutcomeKind::Delivered; }
    /// Delivered, sent on a transport that cannot confirm, or relayed (its broker confirmed it).
    bool ok() const noexcept {
        return kind == OutcomeKind::Delivered || kind == OutcomeKind::Sent || kind == OutcomeKind::Relayed;
    }
    /// "delivered after 1 attempt(s) in 120 µs", "unconfirmed: no acknowledgement after 3 attempt(s)", …
    std::string to_string() const {
        static const char* const kinds[] = {"delivered", "sent", "unconfirmed", "failed",
                                            "sent; the broker confirmed it has it"};
        static const char* const reasons[] = {"", "no acknowledgement", "peer unreachable", "link congested",
                                              "destination inbox full", "destination has no such module",
                                              "transport error", "window full (backpressure)", "shut down",
                                              "other", "the broker refused it or did not confirm it",
                                              "refused by the link"};
        const auto k = static_cast<unsigned>(kind);
        std::string s = k < 5 ? kinds[k] : "other";
        if (reason != HETCOMM_FAIL_REASON_NONE && static_cast<unsigned>(reason) < 12) {
            s += std::string(": ") + reasons[reason];
        }
        s += " after " + std::to_string(attempts) + " attempt(s)";
        if (delivered()) s += " in " + std::to_string(latency.count()) + " us";
        return s;
    }
};

/// The pending outcome of one send. Dropping it does not cancel the send.
class Ticket {
public:
    explicit Ticket(hetcomm_ticket* t) : t_(t) {}
    /// Waits for the outcome (every send ends: the attempt budget bounds it).
    Outcome wait() const {
        hetcomm_outcome o;
        detail::check(hetcomm_ticket_wait(t_.get(), &o));
        return Outcome::from(o);
    }
    /// Waits up to `timeout`; empty if the send has not ended by then.
    std::optional<Outcome> wait_for(std::chrono::milliseconds timeout) const {
        hetcomm_outcome o;
        hetcomm_status s = hetcomm_ticket_wait_timeout(t_.get(), static_cast<std::uint64_t>(timeout.count()), &o);
        if (s == HETCOMM_STATUS_TIMEOUT) return std::nullopt;
        detail::check(s);
        return Outcome::from(o);
    }
    /// The outcome if the send has ended, without waiting.
    std::optional<Outcome> poll() const {
        hetcomm_outcome o;
        hetcomm_status s = hetcomm_ticket_poll(t_.get(), &o);
        if (s == HETCOMM_STATUS_PENDING) return std::nullopt;
        detail::check(s);
        return Outcome::from(o);
    }
    /// The destination system's name.
    std::string_view destination() const { return detail::view(hetcomm_ticket_destination(t_.get())); }

private:
    std::unique_ptr<hetcomm_ticket, detail::TicketDeleter> t_;
};

/// The pending outcomes of one broadcast, one per destination.
class BroadcastTicket {
public:
    explicit BroadcastTicket(hetcomm_broadcast* b) : b_(b) {}
    std::size_t size() const noexcept { return hetcomm_broadcast_count(b_.get()); }
    /// Waits for every destination: (destination, outcome).
    std::vector<std::pair<std::string, Outcome>> wait() const {
        std::vector<std::pair<std::string, Outcome>> out;
        for (std::size_t i = 0; i < size(); ++i) {
            const hetcomm_ticket* t = hetcomm_broadcast_ticket(b_.get(), i);
            hetcomm_outcome o;
            detail::check(hetcomm_ticket_wait(t, &o));
            out.emplace_back(std::string(detail::view(hetcomm_ticket_destination(t))), Outcome::from(o));
        }
        return out;
    }

private:
    std::unique_ptr<hetcomm_broadcast, detail::BroadcastDeleter> b_;
};

/// Where a message came from, when, at which priority.
struct Envelope {
    std::uint32_t message_type = 0;
    std::uint16_t source_system = 0;
    std::uint16_t source_module = 0;
    /// Names live as long as the process.
    std::string_view source_system_name;
    std::string_view source_module_name;
    std::uint64_t seq = 0;
    std::uint64_t timestamp_us = 0;
    std::uint64_t received_at_us = 0;
    std::uint8_t priority = kNormalPriority;
    bool broadcast = false;

    static Envelope from(const hetcomm_envelope& e) {
        return Envelope{e.message_type, e.source_system, e.source_module,
                        detail::view(e.source_system_name), detail::view(e.source_module_name),
                        e.seq, e.timestamp_us, e.received_at_us, e.priority, e.broadcast};
    }
};

/// An undecoded message.
struct RawMessage {
    Envelope envelope;
    std::vector<std::uint8_t> payload;
};

/// A decoded message with its envelope.
template <class T>
struct Received {
    T message;
    Envelope envelope;
};

/// The type id of a message type: `T::hetcomm_id` (HETCOMM_MESSAGE sets it), or specialise
/// this for a type you cannot change.
template <class T, class = void>
struct message_id;
template <class T>
struct message_id<T, std::void_t<decltype(T::hetcomm_id)>> {
    static constexpr std::uint32_t value = T::hetcomm_id;
};

#ifdef HETCOMM_HAS_MSGPACK
/// Encodes a value as a hetcomm payload (one MessagePack value). Floating-point fields are
/// always written as floats (float 64 for double, float 32 for float), as Rust and Python
/// write them; msgpack-c's own packer would write 10.0 as the integer 10.
template <class T>
std::vector<std::uint8_t> encode(const T& value) {
    std::vector<std::uint8_t> out;
    detail::PayloadStream stream{&out};
    msgpack::packer<detail::PayloadStream> packer(stream);
    packer.pack(value);
    return out;
}

/// Decodes exactly one MessagePack value into `T` (trailing bytes are an error, as in Rust).
template <class T>
T decode(Bytes payload) {
    try {
        std::size_t offset = 0;
        msgpack::object_handle oh =
            msgpack::unpack(reinterpret_cast<const char*>(payload.data()), payload.size(), offset);
        if (offset != payload.size()) {
            throw Error(HETCOMM_STATUS_CODEC, "payload has " + std::to_string(payload.size() - offset) +
                                                  " trailing bytes");
        }
        T value{};
        oh.get().convert(value);
        return value;
    } catch (const Error&) {
        throw;
    } catch (const std::exception& e) {
        throw Error(HETCOMM_STATUS_CODEC, std::string("cannot decode payload: ") + e.what());
    }
}
#endif

/// One module of an opened system: send, broadcast, poll, receive, callbacks. Copies share
/// one handle; safe to use from several threads.
class Module {
public:
    /// Sends an encoded payload of type `type` to `module` of `system`. Throws Error when
    /// nothing was sent (unknown name, X pair, too large, window full).
    Ticket send_raw(std::string_view system, std::string_view module, std::uint32_t type, Bytes payload,
                    std::uint8_t priority = kNormalPriority) const {
        hetcomm_ticket* t = nullptr;
        detail::check(hetcomm_module_send(h(), std::string(system).c_str(), std::string(module).c_str(), type,
                                          payload.data(), payload.size(), priority, &t));
        return Ticket(t);
    }
    /// Broadcasts an encoded payload to `module` of every system this one may talk to.
    BroadcastTicket broadcast_raw(std::string_view module, std::uint32_t type, Bytes payload,
                                  std::uint8_t priority = kNormalPriority) const {
        hetcomm_broadcast* b = nullptr;
        detail::check(hetcomm_module_broadcast(h(), std::string(module).c_str(), type, payload.data(),
                                               payload.size(), priority, &b));
        return BroadcastTicket(b);
    }
#ifdef HETCOMM_HAS_MSGPACK
    /// Sends a typed message (its id from message_id<T>).
    template <class T>
    Ticket send(std::string_view system, std::string_view module, const T& msg,
                std::uint8_t priority = kNormalPriority) const {
        return send_raw(system, module, message_id<T>::value, encode(msg), priority);
    }
    /// Broadcasts a typed message.
    template <class T>
    BroadcastTicket broadcast(std::string_view module, const T& msg, std::uint8_t priority = kNormalPriority) const {
        return broadcast_raw(module, message_id<T>::value, encode(msg), priority);
    }
#endif
    /// Whether a message is waiting (CheckForMessage).
    bool has_message() const noexcept { return hetcomm_module_has_message(h()); }
    /// How many messages are waiting.
    std::size_t pending() const noexcept { return hetcomm_module_pending(h()); }
    /// The type of the next message (GetNextMessageType); empty when none waits.
    std::optional<std::uint32_t> next_type() const {
        std::uint32_t t = 0;
        hetcomm_status s = hetcomm_module_next_type(h(), &t);
        if (s == HETCOMM_STATUS_EMPTY) return std::nullopt;
        detail::check(s);
        return t;
    }
    /// Receives the next message of any type: waits up to `timeout` (empty optional: no
    /// message by then); `std::nullopt` timeout waits forever, 0 does not wait.
    std::optional<RawMessage> recv_raw(std::optional<std::chrono::milliseconds> timeout) const {
        hetcomm_message* m = nullptr;
        hetcomm_status s = hetcomm_module_recv_alloc(h(), timeout ? static_cast<std::int64_t>(timeout->count()) : -1, &m);
        if (s == HETCOMM_STATUS_EMPTY || s == HETCOMM_STATUS_TIMEOUT) return std::nullopt;
        detail::check(s);
        std::unique_ptr<hetcomm_message, detail::MessageDeleter> owned(m);
        std::size_t len = 0;
        const std::uint8_t* data = hetcomm_message_data(m, &len);
        return RawMessage{Envelope::from(*hetcomm_message_envelope(m)), std::vector<std::uint8_t>(data, data + len)};
    }
    /// Takes the next message of any type if one waits.
    std::optional<RawMessage> try_recv_raw() const { return recv_raw(std::chrono::milliseconds(0)); }
    /// Receives into the caller's buffer, without allocating: the payload's length, or empty
    /// if no message came within `timeout`. Throws Error with HETCOMM_STATUS_BUFFER_TOO_SMALL
    /// when the next message does not fit (it stays first in line; `needed` gets its size).
    std::optional<std::size_t> recv_into(std::uint8_t* buf, std::size_t capacity, Envelope* envelope,
                                         std::optional<std::chrono::milliseconds> timeout,
                                         std::size_t* needed = nullptr) const {
        std::size_t len = 0;
        hetcomm_envelope env;
        hetcomm_status s = hetcomm_module_recv(h(), timeout ? static_cast<std::int64_t>(timeout->count()) : -1,
                                               buf, capacity, &len, envelope ? &env : nullptr);
        if (s == HETCOMM_STATUS_EMPTY || s == HETCOMM_STATUS_TIMEOUT) return std::nullopt;
        if (s == HETCOMM_STATUS_BUFFER_TOO_SMALL && needed) *needed = len;
        detail::check(s);
        if (envelope) *envelope = Envelope::from(env);
        return len;
    }
#ifdef HETCOMM_HAS_MSGPACK
    /// Takes the next message if one waits and it is a `T` (GetMessage). A message of another
    /// type stays first in line and this throws HETCOMM_STATUS_WRONG_TYPE (as Rust's
    /// RecvError::WrongType); a payload that does not decode as `T` throws
    /// HETCOMM_STATUS_CODEC (the message is consumed: it can never decode).
    template <class T>
    std::optional<Received<T>> try_recv() const { return recv<T>(std::chrono::milliseconds(0)); }
    /// Waits up to `timeout` (nullopt: forever) for the next message, which must be a `T`.
    template <class T>
    std::optional<Received<T>> recv(std::optional<std::chrono::milliseconds> timeout) const {
        hetcomm_message* m = nullptr;
        hetcomm_status s = hetcomm_module_recv_alloc_type(
            h(), message_id<T>::value, timeout ? static_cast<std::int64_t>(timeout->count()) : -1, &m);
        if (s == HETCOMM_STATUS_EMPTY || s == HETCOMM_STATUS_TIMEOUT) return std::nullopt;
        detail::check(s);
        std::unique_ptr<hetcomm_message, detail::MessageDeleter> owned(m);
        std::size_t len = 0;
        const std::uint8_t* data = hetcomm_message_data(m, &len);
        return Received<T>{decode<T>(Bytes(data, len)), Envelope::from(*hetcomm_message_envelope(m))};
    }
#endif
    /// Calls `f(envelope, payload)` on the module's callback thread for every message of type
    /// `type` from now on (callbacks of one module run one at a time). An exception thrown by
    /// `f` is caught and dropped (it cannot cross the C library).
    void on_raw(std::uint32_t type, std::function<void(const Envelope&, Bytes)> f) const {
        auto* slot = store(std::move(f));
        detail::check(hetcomm_module_on(h(), type, &Module::trampoline, slot));
    }
    /// on_raw for every message of a type that has no callback of its own.
    void on_any(std::function<void(const Envelope&, Bytes)> f) const {
        auto* slot = store(std::move(f));
        detail::check(hetcomm_module_on_any(h(), &Module::trampoline, slot));
    }
#ifdef HETCOMM_HAS_MSGPACK
    /// Calls `f` with every `T` that arrives from now on (decoded), on the callback thread. A
    /// payload that does not decode is dropped and counted (stats().callback_failures is the
    /// Rust side's; this wrapper counts in callback_decode_failures()).
    template <class T>
    void on(std::function<void(Received<T>)> f) const {
        auto failures = failures_;
        on_raw(message_id<T>::value, [f = std::move(f), failures](const Envelope& env, Bytes payload) {
            try {
                f(Received<T>{decode<T>(payload), env});
            } catch (const Error&) {
                failures->fetch_add(1);
            }
        });
    }
#endif
    /// Messages a typed callback could not decode.
    std::uint64_t callback_decode_failures() const noexcept { return failures_->load(); }
    /// Lets receives spin up to `spin` before sleeping (lower latency, a busy core).
    void set_wait_spin(std::chrono::microseconds spin) const {
        detail::check(hetcomm_module_set_wait_spin(h(), static_cast<std::uint64_t>(spin.count())));
    }
    /// Runs this module's callbacks on the thread that delivers each message (a link's
    /// reader, the sender's thread in process) instead of its callback thread: short
    /// callbacks that must not wait, possibly on several threads at once.
    void set_inline_callbacks(bool inline_callbacks) const {
        detail::check(hetcomm_module_set_inline_callbacks(h(), inline_callbacks));
    }
    /// This module's inbox counters.
    hetcomm_inbox_stats inbox_stats() const {
        hetcomm_inbox_stats s;
        detail::check(hetcomm_module_inbox_stats(h(), &s));
        return s;
    }
    /// The module's name.
    std::string_view name() const { return detail::view(hetcomm_module_name(h())); }
    /// The C handle (for calls this wrapper does not cover).
    hetcomm_module* handle() const noexcept { return state_->module.get(); }

private:
    friend class Comm;
    using Callback = std::function<void(const Envelope&, Bytes)>;
    /// What the module's callbacks need, kept alive until the system has closed.
    struct CallbackStore {
        std::mutex lock;
        std::vector<std::unique_ptr<Callback>> callbacks;
    };
    struct State {
        // Declared first, destroyed last: callbacks outlive the handles that may run them.
        std::shared_ptr<CallbackStore> callbacks;
        std::shared_ptr<hetcomm_comm> comm;  // keeps the system open while the module lives
        std::unique_ptr<hetcomm_module, detail::ModuleDeleter> module;
    };

    Module(std::shared_ptr<hetcomm_comm> comm, std::shared_ptr<CallbackStore> callbacks, hetcomm_module* m)
        : state_(std::make_shared<State>(State{std::move(callbacks), std::move(comm),
                                               std::unique_ptr<hetcomm_module, detail::ModuleDeleter>(m)})),
          failures_(std::make_shared<std::atomic<std::uint64_t>>(0)) {}

    hetcomm_module* h() const noexcept { return state_->module.get(); }

    Callback* store(Callback f) const {
        std::lock_guard<std::mutex> g(state_->callbacks->lock);
        state_->callbacks->callbacks.push_back(std::make_unique<Callback>(std::move(f)));
        return state_->callbacks->callbacks.back().get();
    }

    static void trampoline(void* user, const hetcomm_envelope* env, const std::uint8_t* data, std::size_t len) {
        try {
            (*static_cast<Callback*>(user))(Envelope::from(*env), Bytes(data, len));
        } catch (...) {
            // Nothing may unwind into the C library.
        }
    }

    std::shared_ptr<State> state_;
    std::shared_ptr<std::atomic<std::uint64_t>> failures_;
};

/// One path switch, copied out of the C API's strings.
struct PathSwitch {
    std::string to, from, now;
    std::uint64_t at_us = 0;
    std::uint64_t number = 0;
};

/// Every path switch of one system from when it was made (`Comm::watch_paths`).
class PathWatch {
public:
    /// The next switch, waiting up to `timeout_ms` (0: do not wait); empty when none came.
    std::optional<PathSwitch> poll(std::uint64_t timeout_ms = 0) {
        hetcomm_path_switch s;
        hetcomm_status st = hetcomm_path_watch_poll(watch_.get(), timeout_ms, &s);
        if (st == HETCOMM_STATUS_EMPTY) return std::nullopt;
        detail::check(st);
        return PathSwitch{s.to, s.from, s.now, s.at_us, s.number};
    }

private:
    friend class Comm;
    struct Deleter { void operator()(hetcomm_path_watch* w) const noexcept { hetcomm_path_watch_free(w); } };
    explicit PathWatch(hetcomm_path_watch* w) : watch_(w) {}
    std::unique_ptr<hetcomm_path_watch, Deleter> watch_;
};

/// One opened system of a fleet. Copies share one handle; the system closes when the last
/// Comm and Module of it are destroyed (after its callback threads have stopped).
class Comm {
public:
    /// Loads a fleet file and opens one system of it.
    static Comm open(const std::string& fleet_path, const std::string& system) {
        hetcomm_comm* c = nullptr;
        detail::check(hetcomm_comm_open(fleet_path.c_str(), system.c_str(), &c));
        return Comm(c);
    }
    /// Opens one system of a fleet given as text (`origin` names it in error messages).
    static Comm from_toml(const std::string& toml, const std::string& system,
                          const std::string& origin = "<fleet>") {
        hetcomm_comm* c = nullptr;
        detail::check(hetcomm_comm_open_str(toml.c_str(), origin.c_str(), system.c_str(), &c));
        return Comm(c);
    }
    /// A module of this system.
    Module module(const std::string& name) const {
        hetcomm_module* m = nullptr;
        detail::check(hetcomm_comm_module(comm_.get(), name.c_str(), &m));
        return Module(comm_, callbacks_, m);
    }
    /// This system's name and id.
    std::string_view name() const { return detail::view(hetcomm_comm_name(comm_.get())); }
    std::uint16_t id() const noexcept { return hetcomm_comm_id(comm_.get()); }
    /// Open transports: (name, listening address or empty).
    std::vector<std::pair<std::string, std::string>> endpoints() const {
        std::vector<std::pair<std::string, std::string>> out;
        for (std::size_t i = 0; i < hetcomm_comm_endpoint_count(comm_.get()); ++i) {
            const char* n = nullptr;
            const char* a = nullptr;
            detail::check(hetcomm_comm_endpoint(comm_.get(), i, &n, &a));
            out.emplace_back(n, a ? a : "");
        }
        return out;
    }
    /// This system's counters.
    hetcomm_stats stats() const {
        hetcomm_stats s;
        detail::check(hetcomm_comm_stats(comm_.get(), &s));
        return s;
    }
    /// Changes, while running, the transports that carry this system's traffic to `system`,
    /// in order of preference (a reorder or subset of the pair's table cell; docs/failover.md).
    /// Throws Error (and changes nothing) when refused.
    void set_transports(const std::string& system, const std::vector<std::string>& transports) const {
        std::vector<const char*> names;
        for (const auto& t : transports) names.push_back(t.c_str());
        detail::check(hetcomm_comm_set_transports(comm_.get(), system.c_str(), names.data(), names.size()));
    }
    /// A watch of this system's path switches from now on (each watch sees every switch).
    PathWatch watch_paths() const;
    /// The C handle.
    hetcomm_comm* handle() const noexcept { return comm_.get(); }

private:
    explicit Comm(hetcomm_comm* c)
        : callbacks_(std::make_shared<Module::CallbackStore>()),
          comm_(std::shared_ptr<hetcomm_comm>(c, detail::CommDeleter{})) {}
    // Declared first, destroyed last (see Module::State).
    std::shared_ptr<Module::CallbackStore> callbacks_;
    std::shared_ptr<hetcomm_comm> comm_;
};

inline PathWatch Comm::watch_paths() const {
    hetcomm_path_watch* w = nullptr;
    detail::check(hetcomm_comm_watch_paths(comm_.get(), &w));
    return PathWatch(w);
}

#ifdef HETCOMM_HAS_MSGPACK
/// The thesis's communication interface (Table 5) over one module, so code written against
/// it reads almost unchanged: Send, CheckForMessage, GetNextMessageType, GetMessage.
class CommInt {
public:
    CommInt(const Comm& comm, const std::string& module) : module_(comm.module(module)) {}
    explicit CommInt(Module module) : module_(std::move(module)) {}

    /// Sends `msg` to `module` of `destination` ("All": every system the table allows) and
    /// waits for the outcome: 1 if delivered (or sent on a transport that cannot confirm; for
    /// "All": on every destination), 0 if not. As in the thesis; use Module::send for the
    /// outcome itself.
    template <class T>
    int Send(const T& msg, const std::string& destination, const std::string& module) const {
        try {
            if (destination == "All") {
                for (auto& [dest, outcome] : module_.broadcast(module, msg).wait()) {
                    if (!outcome.ok()) return 0;
                }
                return 1;
            }
            return module_.send(destination, module, msg).wait().ok() ? 1 : 0;
        } catch (const Error&) {
            return 0;
        }
    }
    /// Whether a message waits.
    bool CheckForMessage() const { return module_.has_message(); }
    /// The next message's type id, or -1 when none waits.
    std::int64_t GetNextMessageType() const {
        auto t = module_.next_type();
        return t ? static_cast<std::int64_t>(*t) : -1;
    }
    /// Takes the next message into `out` if one waits and it is a `T`: true if taken. (The
    /// thesis's setMsgFcnPtr factory is not needed: GetNextMessageType tells which T to ask
    /// for.)
    template <class T>
    bool GetMessage(T& out) const {
        auto t = module_.next_type();
        if (!t || *t != message_id<T>::value) return false;
        auto r = module_.try_recv<T>();
        if (!r) return false;
        out = std::move(r->message);
        return true;
    }
    /// The module underneath (outcomes, callbacks, timeouts).
    const Module& module() const noexcept { return module_; }

private:
    Module module_;
};
#endif

}  // namespace hetcomm

#ifdef HETCOMM_HAS_MSGPACK
/// Inside a struct: its hetcomm type id and its fields, written as a MessagePack map keyed by
/// field name (msgpack-c's MSGPACK_DEFINE_MAP), as Rust and Python write their messages.
#define HETCOMM_MESSAGE(ID, ...)                   \
    static constexpr std::uint32_t hetcomm_id = ID; \
    MSGPACK_DEFINE_MAP(__VA_ARGS__)
#endif

#endif  // HETCOMM_HPP

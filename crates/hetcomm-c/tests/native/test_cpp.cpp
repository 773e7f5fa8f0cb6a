// The C++ wrapper's tests (ctest: cpp_wrapper): typed messages and their bytes, the thesis's
// CommInt facade, errors as hetcomm::Error with the C status, a message of another type stays
// in the inbox, too small a buffer reports the size needed, typed callbacks on the callback
// thread, and handles that outlive each other in any order.
#include <hetcomm.hpp>

#include <atomic>
#include <cstring>
#include <iostream>
#include <map>
#include <thread>

static int checks = 0;
#define CHECK(cond)                                                                     \
    do {                                                                                \
        checks++;                                                                       \
        if (!(cond)) {                                                                  \
            std::cerr << __FILE__ << ":" << __LINE__ << ": check failed: " #cond "\n"; \
            std::exit(1);                                                               \
        }                                                                               \
    } while (0)

template <class F>
static hetcomm_status error_code(F&& f) {
    try {
        f();
    } catch (const hetcomm::Error& e) {
        return e.code();
    }
    return HETCOMM_STATUS_OK;
}

struct Wheels {
    double left = 0, right = 0;
    HETCOMM_MESSAGE(1, left, right)
};
struct Command {
    std::uint8_t code = 0;
    HETCOMM_MESSAGE(0, code)
};
struct Rich {
    std::string label;
    std::vector<std::int32_t> xs;
    std::map<std::string, double> gains;
    bool flag = false;
    HETCOMM_MESSAGE(9, label, xs, gains, flag)
};

static const char* kFleet = R"(
name = "cpp-wrapper"
[systems]
Alpha = 0
Charlie = 1
Tango = 2
[modules]
Plan = 0
Act = 1
[transports.wired]
kind = "inproc"
[table]
columns = ["Alpha", "Charlie", "Tango"]
Alpha = ["X", "wired", "wired"]
Charlie = ["wired", "X", "X"]
Tango = ["wired", "X", "X"]
)";

int main() {
    using namespace std::chrono_literals;
    // The bytes are the documented encoding: docs/wire-format.md's Wheels { left: -10.0, right: 10.0 }.
    auto bytes = hetcomm::encode(Wheels{-10.0, 10.0});
    const std::uint8_t expected[] = {0x82, 0xa4, 'l', 'e', 'f', 't', 0xcb, 0xc0, 0x24, 0, 0, 0, 0, 0, 0,
                                     0xa5, 'r', 'i', 'g', 'h', 't', 0xcb, 0x40, 0x24, 0, 0, 0, 0, 0, 0};
    CHECK(bytes.size() == sizeof expected && std::memcmp(bytes.data(), expected, sizeof expected) == 0);
    // Lenient like Rust: keys in any order, unknown keys ignored, ints for floats.
    const std::uint8_t reordered[] = {0x83, 0xa5, 'r', 'i', 'g', 'h', 't', 0x05, 0xa1, 'z', 0xc0, 0xa4, 'l', 'e', 'f', 't', 0xff};
    Wheels w = hetcomm::decode<Wheels>(hetcomm::Bytes(reordered, sizeof reordered));
    CHECK(w.left == -1.0 && w.right == 5.0);
    const std::uint8_t trailing[] = {0x81, 0xa4, 'c', 'o', 'd', 'e', 0x01, 0x00};
    CHECK(error_code([&] { hetcomm::decode<Command>(hetcomm::Bytes(trailing, sizeof trailing)); }) == HETCOMM_STATUS_CODEC);
    const std::uint8_t not_a_map[] = {0xa3, 'a', 'b', 'c'};
    CHECK(error_code([&] { hetcomm::decode<Wheels>(hetcomm::Bytes(not_a_map, sizeof not_a_map)); }) == HETCOMM_STATUS_CODEC);

    // A refused send (a bridge that cannot convert it) says so, not "other".
    hetcomm_outcome refused{HETCOMM_OUTCOME_KIND_FAILED, 1, 0, HETCOMM_FAIL_REASON_REFUSED};
    CHECK(hetcomm::Outcome::from(refused).to_string() == "failed: refused by the link after 1 attempt(s)");

    // Errors are exceptions carrying the C status.
    CHECK(error_code([] { hetcomm::Comm::from_toml("[systems]\nA = -1\n", "A", "bad.toml"); }) == HETCOMM_STATUS_CONFIG);
    CHECK(error_code([] { hetcomm::Comm::from_toml(kFleet, "Zulu"); }) == HETCOMM_STATUS_UNKNOWN_SYSTEM);
    try {
        hetcomm::Comm::from_toml(kFleet, "Zulu", "named.toml");
        CHECK(false);
    } catch (const hetcomm::Error& e) {
        CHECK(std::string(e.what()).find("Zulu") != std::string::npos);
    }

    std::atomic<int> typed_calls{0};
    std::atomic<bool> on_other_thread{true};
    {
        auto alpha = hetcomm::Comm::from_toml(kFleet, "Alpha");
        auto charlie = hetcomm::Comm::from_toml(kFleet, "Charlie");
        auto tango = hetcomm::Comm::from_toml(kFleet, "Tango");
        auto plan = alpha.module("Plan");
        auto act = charlie.module("Act");
        CHECK(error_code([&] { alpha.module("Nope"); }) == HETCOMM_STATUS_UNKNOWN_MODULE);
        CHECK(error_code([&] { plan.send("Alpha", "Act", Command{1}); }) == HETCOMM_STATUS_NO_ROUTE);
        CHECK(alpha.name() == "Alpha" && alpha.id() == 0 && plan.name() == "Plan");

        // Typed round trip with every field kind.
        Rich r{"ünï", {-1, 0, 1 << 20}, {{"kp", 0.5}, {"ki", -2.0}}, true};
        auto outcome = plan.send("Charlie", "Act", r, 200).wait();
        CHECK(outcome.delivered() && outcome.ok() && outcome.to_string().rfind("delivered", 0) == 0);
        auto got = act.recv<Rich>(1s);
        CHECK(got && got->message.label == r.label && got->message.xs == r.xs && got->message.gains == r.gains &&
              got->message.flag && got->envelope.priority == 200 && got->envelope.source_system_name == "Alpha");
        CHECK(!act.try_recv<Rich>());

        // A message of another type stays in the inbox.
        plan.send("Charlie", "Act", Command{2}).wait();
        CHECK(error_code([&] { act.try_recv<Wheels>(); }) == HETCOMM_STATUS_WRONG_TYPE);
        CHECK(error_code([&] { act.recv<Wheels>(50ms); }) == HETCOMM_STATUS_WRONG_TYPE);
        CHECK(act.has_message() && act.next_type() == std::optional<std::uint32_t>(0));
        // Too small a buffer: the size needed; the message still stays.
        std::uint8_t tiny[2];
        std::size_t needed = 0;
        hetcomm::Envelope env;
        try {
            act.recv_into(tiny, sizeof tiny, &env, 0ms, &needed);
            CHECK(false);
        } catch (const hetcomm::Error& e) {
            CHECK(e.code() == HETCOMM_STATUS_BUFFER_TOO_SMALL && needed == 7);
        }
        auto cmd = act.try_recv<Command>();
        CHECK(cmd && cmd->message.code == 2);
        CHECK(!act.recv_raw(20ms));

        // The thesis's facade.
        hetcomm::CommInt alpha_plan(alpha, "Plan"), charlie_act(charlie, "Act");
        CHECK(alpha_plan.Send(Wheels{1.5, -1.5}, "Charlie", "Act") == 1);
        CHECK(alpha_plan.Send(Wheels{}, "Nowhere", "Act") == 0);
        CHECK(charlie_act.CheckForMessage());
        CHECK(charlie_act.GetNextMessageType() == 1);
        Command wrong;
        CHECK(!charlie_act.GetMessage(wrong));  // not a Command: stays
        Wheels ww;
        CHECK(charlie_act.GetMessage(ww) && ww.left == 1.5 && ww.right == -1.5);
        CHECK(!charlie_act.CheckForMessage() && charlie_act.GetNextMessageType() == -1);
        CHECK(alpha_plan.Send(Command{3}, "All", "Act") == 1);  // broadcast to Charlie and Tango
        auto tango_act = tango.module("Act");
        CHECK(tango_act.recv<Command>(1s)->envelope.broadcast);
        CHECK(act.recv<Command>(1s)->message.code == 3);
        auto b = plan.broadcast("Act", Command{4});
        auto outcomes = b.wait();
        CHECK(outcomes.size() == 2 && outcomes[0].second.delivered() && outcomes[1].second.delivered());

        // Typed callbacks on the callback thread; a payload that does not decode is counted.
        auto main_id = std::this_thread::get_id();
        act.on<Wheels>([&, main_id](hetcomm::Received<Wheels> rw) {
            if (std::this_thread::get_id() == main_id) on_other_thread = false;
            if (rw.message.left == 7.0) typed_calls++;
        });
        for (int i = 0; i < 5; i++) plan.send("Charlie", "Act", Wheels{7.0, 0.0});
        const std::uint8_t junk[] = {0xc1};
        plan.send_raw("Charlie", "Act", Wheels::hetcomm_id, hetcomm::Bytes(junk, 1)).wait();
        for (int i = 0; i < 1000 && (typed_calls < 5 || act.callback_decode_failures() < 1); i++)
            std::this_thread::sleep_for(1ms);
        CHECK(typed_calls == 5 && act.callback_decode_failures() == 1);
        // A callback that throws does not stop the next one.
        act.on_raw(8, [](const hetcomm::Envelope&, hetcomm::Bytes) { throw std::runtime_error("ignored"); });
        plan.send_raw("Charlie", "Act", 8, hetcomm::Bytes(junk, 1)).wait();
        plan.send("Charlie", "Act", Wheels{7.0, 1.0}).wait();
        for (int i = 0; i < 1000 && typed_calls < 6; i++) std::this_thread::sleep_for(1ms);
        CHECK(typed_calls == 6 && on_other_thread);

        auto stats = alpha.stats();
        CHECK(stats.sends >= 12 && stats.failed == 0);
        CHECK(act.inbox_stats().dropped == 0);
        // Handles destroyed in any order: the Comm first while a Module (and its callbacks) lives.
    }
    // Copies share one system: the module keeps it open after the Comm object is gone.
    std::optional<hetcomm::Module> kept;
    {
        auto alpha = hetcomm::Comm::from_toml(kFleet, "Alpha", "second.toml");
        auto charlie = hetcomm::Comm::from_toml(kFleet, "Charlie", "second.toml");
        kept = charlie.module("Act");
        kept->on<Command>([&](hetcomm::Received<Command>) { typed_calls++; });
        alpha.module("Plan").send("Charlie", "Act", Command{1}).wait();
    }
    for (int i = 0; i < 1000 && typed_calls < 7; i++) std::this_thread::sleep_for(1ms);
    CHECK(typed_calls == 7);
    kept.reset();
    // A pair with two transports moved while running; the watch sees both moves.
    {
        const char* two = "[systems]\nA = 0\nB = 1\n[modules]\nM = 0\n"
                          "[transports.wired]\nkind = \"inproc\"\n[transports.spare]\nkind = \"inproc\"\n"
                          "[table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"wired,spare\"]\nB = [\"wired,spare\", \"X\"]\n";
        auto a = hetcomm::Comm::from_toml(two, "A", "paths.toml");
        auto b = hetcomm::Comm::from_toml(two, "B", "paths.toml");
        auto watch = a.watch_paths();
        CHECK(!watch.poll());
        a.set_transports("B", {"spare"});
        a.set_transports("B", {"wired", "spare"});
        auto first = watch.poll(1000);
        CHECK(first && first->to == "B" && first->from == "wired" && first->now == "spare" && first->number == 1);
        auto second = watch.poll(1000);
        CHECK(second && second->from == "spare" && second->now == "wired" && second->number == 2);
        CHECK(error_code([&] { a.set_transports("B", {"radio"}); }) == HETCOMM_STATUS_INVALID_ARGUMENT);
        CHECK(!watch.poll(10));
    }
    std::cout << "test_cpp: " << checks << " checks passed" << std::endl;
    return 0;
}

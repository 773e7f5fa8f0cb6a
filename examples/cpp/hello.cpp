// hello.cpp: the C++ wrapper in one file. Typed messages (MessagePack maps, the same bytes as
// the Rust and Python types of the same fields), outcomes, polling, a callback, and the
// thesis's CommInt facade (Send / CheckForMessage / GetNextMessageType / GetMessage).
//
//   hello_cpp [FLEET]     (default: examples/c/hello.toml)
#include <hetcomm.hpp>

#include <atomic>
#include <chrono>
#include <iostream>
#include <thread>

// Rust: #[derive(Serialize, Deserialize, Message)] #[message(id = 0)] struct Command { code: u8 }
// Python: @hetcomm.message(id=0) @dataclass class Command: code: int
struct Command {
    std::uint8_t code = 0;
    HETCOMM_MESSAGE(0, code)
};

int main(int argc, char** argv) {
    const std::string fleet = argc > 1 ? argv[1] : HELLO_FLEET;
    try {
        auto alpha = hetcomm::Comm::open(fleet, "Alpha");
        auto charlie = hetcomm::Comm::open(fleet, "Charlie");
        auto plan = alpha.module("Plan");
        auto act = charlie.module("Act");

        // A send returns a ticket at once; its outcome says what the sender knows.
        hetcomm::Outcome outcome = plan.send("Charlie", "Act", Command{1}).wait();
        std::cout << "send: " << outcome.to_string() << "\n";
        if (auto got = act.recv<Command>(std::chrono::seconds(1))) {
            std::cout << "Charlie.Act: code " << int(got->message.code) << " from "
                      << got->envelope.source_system_name << "." << got->envelope.source_module_name << "\n";
        }

        // The thesis's API, nearly unchanged.
        hetcomm::CommInt alpha_plan(alpha, "Plan"), charlie_act(charlie, "Act");
        int ok = alpha_plan.Send(Command{2}, "Charlie", "Act");  // 1: delivered
        std::cout << "Send returned " << ok << "\n";
        if (charlie_act.CheckForMessage() && charlie_act.GetNextMessageType() == Command::hetcomm_id) {
            Command c;
            if (charlie_act.GetMessage(c)) std::cout << "GetMessage: code " << int(c.code) << "\n";
        }

        // Callbacks run on the module's callback thread.
        std::atomic<int> seen{0};
        act.on<Command>([&](hetcomm::Received<Command> r) {
            std::cout << "callback: code " << int(r.message.code) << "\n";
            seen++;
        });
        plan.send("Charlie", "Act", Command{0}).wait();
        for (int i = 0; i < 500 && seen == 0; i++) std::this_thread::sleep_for(std::chrono::milliseconds(2));
        auto stats = alpha.stats();
        std::cout << "Alpha: " << stats.sends << " sends, " << stats.delivered << " delivered\n";
        return seen == 1 && ok == 1 ? 0 : 1;
    } catch (const hetcomm::Error& e) {
        std::cerr << e.what() << "\n";
        return 1;
    }
}

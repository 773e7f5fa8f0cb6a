// Tango, a follower rover of the leader–follower demonstration (the thesis's Fig. 26), in C++.
//
// The same autonomy code as the Rust follower (examples/leader_follower) and the Python one
// (examples/python/tango.py): every control period (0.1 s) Tango's Plan module polls for
// Commands from its leader (Charlie) and, when one came, switches its motion; its Act module
// then reports its Wheels to its virtual environment. With no new command it keeps the
// previous motion. Which transport carries each message is the fleet file's business.
//
//   tango FLEET [--as Tango] [--env VirtualEnv3] [--period 0.1] [--duration S] [--exit-on-stop]
//
// In the demo (Alpha, Charlie and the virtual environments in the Rust demo, this process as
// Tango over UDP):
//   tango examples/cpp/leader-follower-cpp.toml
//   hetcomm demo --realtime --fleet examples/cpp/leader-follower-cpp.toml --external Tango
#include <hetcomm.hpp>

#include <chrono>
#include <cstring>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

// The same type ids and fields as the Rust Command and Wheels.
struct Command {
    std::uint8_t code = 0;  // 0 straight, 1 turn left, 2 stop
    HETCOMM_MESSAGE(0, code)
};
struct Wheels {
    double left = 0, right = 0;
    HETCOMM_MESSAGE(1, left, right)
    bool operator==(const Wheels& o) const { return left == o.left && right == o.right; }
};

constexpr int kStop = 2;

// Wheel speeds for a command code (Fig. 26): straight 1/1, left pivot -10/+10, stop 0/0.
Wheels wheels_for(int code) {
    if (code == 1) return {-10.0, 10.0};
    if (code == kStop) return {0.0, 0.0};
    return {1.0, 1.0};
}

int main(int argc, char** argv) {
    if (argc < 2) {
        std::cerr << "usage: tango FLEET [--as SYSTEM] [--env SYSTEM] [--period S] [--duration S] [--exit-on-stop]\n";
        return 2;
    }
    std::string fleet = argv[1], system = "Tango", env = "VirtualEnv3";
    double period = 0.1, duration = -1;
    bool exit_on_stop = false;
    for (int i = 2; i < argc; i++) {
        std::string a = argv[i];
        auto value = [&](const char* name) -> std::string {
            if (i + 1 >= argc) throw std::invalid_argument(std::string(name) + " needs a value");
            return argv[++i];
        };
        try {
            if (a == "--as") system = value("--as");
            else if (a == "--env") env = value("--env");
            else if (a == "--period") period = std::stod(value("--period"));
            else if (a == "--duration") duration = std::stod(value("--duration"));
            else if (a == "--exit-on-stop") exit_on_stop = true;
            else throw std::invalid_argument("unknown argument " + a);
        } catch (const std::exception& e) {
            std::cerr << "tango: " << e.what() << "\n";
            return 2;
        }
    }
    try {
        auto comm = hetcomm::Comm::open(fleet, system);
        auto plan = comm.module("Plan");
        auto act = comm.module("Act");
        std::string name(comm.name());
        std::string endpoints;
        for (auto& [t, a] : comm.endpoints()) endpoints += (endpoints.empty() ? "" : ", ") + t + " " + (a.empty() ? "(in-process)" : a);
        Wheels wheels = wheels_for(0);  // every rover starts driving straight
        std::vector<int> commands;
        std::cout << name << ": ready on " << endpoints << std::endl;
        std::cout << name << ": wheels left=" << wheels.left << " right=" << wheels.right << std::endl;

        auto start = std::chrono::steady_clock::now();
        auto next = start;
        auto step = std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(period));
        while (duration < 0 || std::chrono::steady_clock::now() - start < std::chrono::duration<double>(duration)) {
            // One control step: take every waiting command, then report the wheels.
            while (plan.has_message()) {
                auto type = plan.next_type();
                if (type != Command::hetcomm_id) {
                    auto other = plan.try_recv_raw();
                    if (other) std::cout << name << ": ignoring a message of type " << other->envelope.message_type << std::endl;
                    continue;
                }
                auto r = plan.try_recv<Command>();
                if (!r) break;
                commands.push_back(r->message.code);
                std::cout << name << ": command " << int(r->message.code) << " from " << r->envelope.source_system_name
                          << "." << r->envelope.source_module_name << " (id " << r->envelope.source_system << ":"
                          << r->envelope.seq << ")" << std::endl;
                Wheels w = wheels_for(r->message.code);
                if (!(w == wheels)) std::cout << name << ": wheels left=" << w.left << " right=" << w.right << std::endl;
                wheels = w;
            }
            // Periodic data: a lost report is replaced by the next one; the outcome is not waited for.
            act.send(env, "World", wheels);
            if (exit_on_stop && !commands.empty() && commands.back() == kStop) break;
            next += step;
            std::this_thread::sleep_until(next);
        }
        // Let the last report reach the environment before the system closes.
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
        std::cout << name << ": done after " << commands.size() << " commands" << std::endl;
        return 0;
    } catch (const hetcomm::Error& e) {
        std::cerr << "tango: " << e.what() << "\n";
        return 1;
    }
}

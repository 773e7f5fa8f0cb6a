// The C++ side of the interop tests (run by ctest through drive.py): system Cpp sends a typed
// Sample to the peer process (Rust or Python) over the fleet's transport, checks that the
// acknowledged send was delivered, then receives the peer's changed Sample and checks every
// field. Exits 0 when all held.
//
//   interop FLEET
#include <hetcomm.hpp>

#include <iostream>
#include <string>
#include <vector>

// Rust: struct Sample { name: String, x: f64, count: i64, values: Vec<u32>, ok: bool }, id 7.
struct Sample {
    std::string name;
    double x = 0;
    std::int64_t count = 0;
    std::vector<std::uint32_t> values;
    bool ok = false;
    HETCOMM_MESSAGE(7, name, x, count, values, ok)
};

#define CHECK(cond)                                                              \
    do {                                                                         \
        if (!(cond)) {                                                           \
            std::cerr << "interop: check failed: " #cond " (line " << __LINE__ << ")\n"; \
            return 1;                                                            \
        }                                                                        \
    } while (0)

int main(int argc, char** argv) {
    if (argc != 2) {
        std::cerr << "usage: interop FLEET\n";
        return 2;
    }
    try {
        auto comm = hetcomm::Comm::open(argv[1], "Cpp");
        auto m = comm.module("M");
        Sample s{"from C++ ✓", 3.0, -300, {1, 200, 70000}, true};
        auto outcome = m.send("Peer", "M", s).wait();
        std::cout << "cpp: send " << outcome.to_string() << std::endl;
        CHECK(outcome.delivered());
        CHECK(outcome.attempts >= 1);

        auto r = m.recv<Sample>(std::chrono::seconds(20));
        CHECK(r.has_value());
        const Sample& b = r->message;
        std::cout << "cpp: got name=" << b.name << " x=" << b.x << " count=" << b.count
                  << " values=" << b.values.size() << " ok=" << b.ok << " from " << r->envelope.source_system_name
                  << std::endl;
        CHECK(b.name == s.name + " back");
        CHECK(b.x == 6.0);
        CHECK(b.count == -301);
        CHECK((b.values == std::vector<std::uint32_t>{1, 200, 70000, 3}));
        CHECK(b.ok == false);
        CHECK(r->envelope.source_system_name == "Peer");
        auto stats = comm.stats();
        CHECK(stats.delivered == 1 && stats.received == 1);
        std::cout << "cpp: ok" << std::endl;
        return 0;
    } catch (const hetcomm::Error& e) {
        std::cerr << "interop: " << e.what() << "\n";
        return 1;
    }
}

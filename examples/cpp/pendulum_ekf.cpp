// A pendulum tracked by an extended Kalman filter, served to autotune as a worker
// (docs/external.md). Plain C++17, no libraries beyond the standard one (and, for
// `--format sums` alone, autotune's worker library).
//
// State x = (theta, omega): angle from the vertical (rad) and angular rate (rad/s).
// Truth, per step of dt:   theta' = theta + omega dt
//                          omega' = omega - (g/L) sin(theta) dt
//                          plus w ~ N(0, q Qd), Qd = [dt^3/3, dt^2/2; dt^2/2, dt]
// Sensor "bob": the bob's position z = (L sin theta, -L cos theta) + v, v ~ N(0, r I).
// The truth's q and r are fixed below (Q_TRUE, R_TRUE); the filter's come from the
// request's theta = {"q": .., "r": ..}.
//
// Seed contract: run i's random numbers come from a xoshiro256++ stream seeded by
// splitmix64 from (seed, i) alone, drawn in a fixed order (initial error, then per step
// the process noise and the measurement noise), so every candidate sees the same noise.
//
// Records: e, P, nu_bob, S_bob as float64 arrays with leading axes (runs, steps), written
// as an uncompressed .npz (what np.savez writes) into the request's dir. `--format csv`
// or `--format jsonl` writes the same records as CSV or JSON Lines instead (for comparing
// the formats' speed).
//
// Sums: built with -DAUTOTUNE_SUMS against autotune's C library (include/autotune.h,
// libautotune.so from `cargo build --release -p autotune-cdylib`), `--format sums`
// keeps no records: each step's e, P, nu_bob and S_bob go to the library as they are
// computed, and the answer is the line it makes, {"id": .., "sums": ".."}: the sums of
// exactly the numbers the .npz would hold, so autotune's statistics are the same bit for
// bit. `--self-time sums|none N T [LAGS]` times the worker's own work on runs [0, N) in
// chunks of 64, with no protocol (theta and seed of pendulum.toml's start): the filter
// alone (none), or the filter feeding the library and making each chunk's answer (sums).
//
// Build: g++ -O2 -std=c++17 -o pendulum_ekf pendulum_ekf.cpp
// With sums, from the repository root, the library in target/release (examples/cpp/ci.sh):
//   g++ -O2 -std=c++17 -DAUTOTUNE_SUMS -I include -o pendulum_ekf examples/cpp/pendulum_ekf.cpp
//       -L target/release -lautotune -Wl,-rpath,$PWD/target/release

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#ifdef AUTOTUNE_SUMS
#include "autotune.h"
#endif

namespace {

constexpr double G_OVER_L = 9.81;  // 1/s^2 (L = 1 m)
constexpr double L = 1.0;          // m
constexpr double DT = 0.05;        // s
constexpr double Q_TRUE = 0.05;    // (rad/s^2)^2 / Hz
constexpr double R_TRUE = 0.01;    // m^2
constexpr double THETA0 = 0.5;     // rad
constexpr double P0 = 0.01;        // initial variance of each state component

// ---------------------------------------------------------------- random numbers

uint64_t splitmix64(uint64_t& s) {
    uint64_t z = (s += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

struct Rng {
    uint64_t s[4];
    bool has_spare = false;
    double spare = 0.0;

    // The stream of run i under seed: a function of (seed, i) only.
    Rng(uint64_t seed, uint64_t run) {
        uint64_t sm = seed;
        uint64_t mixed = splitmix64(sm) ^ run;
        for (auto& w : s) w = splitmix64(mixed);
    }
    static uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
    uint64_t next() {
        uint64_t result = rotl(s[0] + s[3], 23) + s[0];
        uint64_t t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = rotl(s[3], 45);
        return result;
    }
    // Uniform in (0, 1].
    double uniform() { return ((next() >> 11) + 1) * 0x1.0p-53; }
    // Standard normal, Box-Muller.
    double normal() {
        if (has_spare) {
            has_spare = false;
            return spare;
        }
        double r = std::sqrt(-2.0 * std::log(uniform()));
        double a = 2.0 * M_PI * uniform();
        spare = r * std::sin(a);
        has_spare = true;
        return r * std::cos(a);
    }
};

// ---------------------------------------------------------------- a tiny JSON reader

// Just what a request needs: objects, arrays, strings, numbers (kept as text, so that a
// 64-bit seed is parsed exactly), true/false/null.
struct Json {
    enum Kind { Null, Bool, Number, String, Array, Object } kind = Null;
    std::string text;  // a number's literal, or a string's value
    std::vector<Json> items;
    std::vector<std::pair<std::string, Json>> members;  // in the order received

    const Json& at(const std::string& key) const {
        for (const auto& m : members)
            if (m.first == key) return m.second;
        throw std::runtime_error("request has no \"" + key + "\"");
    }
    double number() const {
        if (kind != Number) throw std::runtime_error("expected a number");
        return std::stod(text);
    }
    uint64_t u64() const {
        if (kind != Number || text.empty() || text[0] == '-')
            throw std::runtime_error("expected a non-negative integer");
        return std::stoull(text);
    }
};

struct Parser {
    const std::string& s;
    size_t i = 0;

    void ws() {
        while (i < s.size() && (s[i] == ' ' || s[i] == '\t' || s[i] == '\r' || s[i] == '\n')) i++;
    }
    [[noreturn]] void fail(const char* what) {
        throw std::runtime_error(std::string("bad JSON: ") + what + " at byte " + std::to_string(i));
    }
    char peek() {
        ws();
        if (i >= s.size()) fail("unexpected end");
        return s[i];
    }
    void expect(char c) {
        if (peek() != c) fail("unexpected character");
        i++;
    }
    std::string string() {
        expect('"');
        std::string out;
        while (true) {
            if (i >= s.size()) fail("unterminated string");
            char c = s[i++];
            if (c == '"') return out;
            if (c != '\\') {
                out += c;
                continue;
            }
            if (i >= s.size()) fail("unterminated escape");
            char e = s[i++];
            switch (e) {
                case '"': out += '"'; break;
                case '\\': out += '\\'; break;
                case '/': out += '/'; break;
                case 'b': out += '\b'; break;
                case 'f': out += '\f'; break;
                case 'n': out += '\n'; break;
                case 'r': out += '\r'; break;
                case 't': out += '\t'; break;
                case 'u': {
                    if (i + 4 > s.size()) fail("short \\u escape");
                    unsigned cp = std::stoul(s.substr(i, 4), nullptr, 16);
                    i += 4;
                    // Enough for paths: encode the code unit as UTF-8 (no surrogate pairs).
                    if (cp < 0x80) {
                        out += char(cp);
                    } else if (cp < 0x800) {
                        out += char(0xC0 | (cp >> 6));
                        out += char(0x80 | (cp & 0x3F));
                    } else {
                        out += char(0xE0 | (cp >> 12));
                        out += char(0x80 | ((cp >> 6) & 0x3F));
                        out += char(0x80 | (cp & 0x3F));
                    }
                    break;
                }
                default: fail("unknown escape");
            }
        }
    }
    Json value() {
        Json v;
        char c = peek();
        if (c == '{') {
            v.kind = Json::Object;
            i++;
            if (peek() == '}') {
                i++;
                return v;
            }
            while (true) {
                std::string key = string();
                expect(':');
                v.members.emplace_back(key, value());
                if (peek() == ',') {
                    i++;
                    continue;
                }
                expect('}');
                return v;
            }
        }
        if (c == '[') {
            v.kind = Json::Array;
            i++;
            if (peek() == ']') {
                i++;
                return v;
            }
            while (true) {
                v.items.push_back(value());
                if (peek() == ',') {
                    i++;
                    continue;
                }
                expect(']');
                return v;
            }
        }
        if (c == '"') {
            v.kind = Json::String;
            v.text = string();
            return v;
        }
        for (const char* word : {"true", "false", "null"}) {
            size_t n = std::strlen(word);
            if (s.compare(i, n, word) == 0) {
                i += n;
                v.kind = word[0] == 'n' ? Json::Null : Json::Bool;
                v.text = word;
                return v;
            }
        }
        size_t start = i;
        while (i < s.size() && std::strchr("+-0123456789.eE", s[i])) i++;
        if (i == start) fail("unexpected character");
        v.kind = Json::Number;
        v.text = s.substr(start, i - start);
        return v;
    }
};

std::string json_string(const std::string& s) {
    std::string out = "\"";
    for (unsigned char c : s) {
        if (c == '"' || c == '\\') {
            out += '\\';
            out += char(c);
        } else if (c < 0x20) {
            char buf[8];
            std::snprintf(buf, sizeof buf, "\\u%04x", c);
            out += buf;
        } else {
            out += char(c);
        }
    }
    return out + "\"";
}

// ---------------------------------------------------------------- the experiment

// One step of one run: what the records hold (P and S row-major).
struct Step {
    double e[2], P[4], nu[2], S[4];
};

// Runs [a, b) of `steps` steps each, calling put(run, step, const Step&) after each step
// (step 1-based, runs in order, each run's steps in order).
template <class Put>
void simulate(double q, double r, uint64_t seed, uint64_t a, uint64_t b, size_t steps, Put&& put) {
    const double dt = DT;
    // Qd = [dt^3/3, dt^2/2; dt^2/2, dt] and its Cholesky factor, for the truth's noise.
    const double qd11 = dt * dt * dt / 3, qd12 = dt * dt / 2, qd22 = dt;
    const double c11 = std::sqrt(Q_TRUE * qd11), c21 = Q_TRUE * qd12 / c11;
    const double c22 = std::sqrt(Q_TRUE * qd22 - c21 * c21);
    const double sr = std::sqrt(R_TRUE);
    for (uint64_t run = a; run < b; run++) {
        Rng rng(seed, run);
        double th = THETA0 + std::sqrt(P0) * rng.normal();
        double om = std::sqrt(P0) * rng.normal();
        double xh[2] = {THETA0, 0.0};
        double P[2][2] = {{P0, 0.0}, {0.0, P0}};
        for (size_t k = 0; k < steps; k++) {
            // Truth and its measurement.
            double w1 = rng.normal(), w2 = rng.normal();
            double th_n = th + om * dt + c11 * w1;
            double om_n = om - G_OVER_L * std::sin(th) * dt + c21 * w1 + c22 * w2;
            th = th_n;
            om = om_n;
            double z[2] = {L * std::sin(th) + sr * rng.normal(), -L * std::cos(th) + sr * rng.normal()};

            // EKF predict.
            double F[2][2] = {{1.0, dt}, {-G_OVER_L * std::cos(xh[0]) * dt, 1.0}};
            double xp[2] = {xh[0] + xh[1] * dt, xh[1] - G_OVER_L * std::sin(xh[0]) * dt};
            double FP[2][2], Pp[2][2];
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++) FP[i][j] = F[i][0] * P[0][j] + F[i][1] * P[1][j];
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++) Pp[i][j] = FP[i][0] * F[j][0] + FP[i][1] * F[j][1];
            Pp[0][0] += q * qd11;
            Pp[0][1] += q * qd12;
            Pp[1][0] += q * qd12;
            Pp[1][1] += q * qd22;

            // EKF update: h(x) = (L sin theta, -L cos theta), H = [L cos, 0; L sin, 0].
            double H[2][2] = {{L * std::cos(xp[0]), 0.0}, {L * std::sin(xp[0]), 0.0}};
            double nu[2] = {z[0] - L * std::sin(xp[0]), z[1] + L * std::cos(xp[0])};
            double PHt[2][2], S[2][2];
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++) PHt[i][j] = Pp[i][0] * H[j][0] + Pp[i][1] * H[j][1];
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++) S[i][j] = H[i][0] * PHt[0][j] + H[i][1] * PHt[1][j];
            S[0][0] += r;
            S[1][1] += r;
            double det = S[0][0] * S[1][1] - S[0][1] * S[1][0];
            double Si[2][2] = {{S[1][1] / det, -S[0][1] / det}, {-S[1][0] / det, S[0][0] / det}};
            double K[2][2];
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++) K[i][j] = PHt[i][0] * Si[0][j] + PHt[i][1] * Si[1][j];
            for (int i = 0; i < 2; i++) xh[i] = xp[i] + K[i][0] * nu[0] + K[i][1] * nu[1];
            // Joseph form: P = (I - K H) Pp (I - K H)' + r K K'.
            double A[2][2], AP[2][2];
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++)
                    A[i][j] = (i == j ? 1.0 : 0.0) - (K[i][0] * H[0][j] + K[i][1] * H[1][j]);
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++) AP[i][j] = A[i][0] * Pp[0][j] + A[i][1] * Pp[1][j];
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++)
                    P[i][j] = AP[i][0] * A[j][0] + AP[i][1] * A[j][1] +
                              r * (K[i][0] * K[j][0] + K[i][1] * K[j][1]);
            double sym = 0.5 * (P[0][1] + P[1][0]);
            P[0][1] = P[1][0] = sym;

            Step out;
            out.e[0] = th - xh[0];
            out.e[1] = om - xh[1];
            out.nu[0] = nu[0];
            out.nu[1] = nu[1];
            for (int i = 0; i < 2; i++)
                for (int j = 0; j < 2; j++) {
                    out.P[i * 2 + j] = P[i][j];
                    out.S[i * 2 + j] = S[i][j];
                }
            put(run, k + 1, out);
        }
    }
}

// Records of runs [a, b): each array flat in C order with leading axes (b - a, steps).
struct Records {
    size_t runs, steps;
    std::vector<double> e, P, nu, S;  // (.., 2), (.., 2, 2), (.., 2), (.., 2, 2)
};

Records records(double q, double r, uint64_t seed, uint64_t a, uint64_t b, size_t steps) {
    Records out{size_t(b - a), steps, {}, {}, {}, {}};
    size_t cells = out.runs * steps;
    out.e.resize(cells * 2);
    out.P.resize(cells * 4);
    out.nu.resize(cells * 2);
    out.S.resize(cells * 4);
    simulate(q, r, seed, a, b, steps, [&](uint64_t run, size_t step, const Step& s) {
        size_t cell = (run - a) * steps + (step - 1);
        std::copy(s.e, s.e + 2, &out.e[cell * 2]);
        std::copy(s.P, s.P + 4, &out.P[cell * 4]);
        std::copy(s.nu, s.nu + 2, &out.nu[cell * 2]);
        std::copy(s.S, s.S + 4, &out.S[cell * 4]);
    });
    return out;
}

// ---------------------------------------------------------------- writing records

uint32_t crc32(const std::string& data) {
    static uint32_t table[256];
    static bool ready = false;
    if (!ready) {
        for (uint32_t n = 0; n < 256; n++) {
            uint32_t c = n;
            for (int k = 0; k < 8; k++) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
            table[n] = c;
        }
        ready = true;
    }
    uint32_t c = 0xFFFFFFFFu;
    for (unsigned char b : data) c = table[(c ^ b) & 0xFF] ^ (c >> 8);
    return c ^ 0xFFFFFFFFu;
}

// A .npy file (format 1.0) of little-endian float64 in C order.
std::string npy(const std::vector<double>& data, const std::vector<size_t>& shape) {
    std::string dims;
    for (size_t d : shape) dims += std::to_string(d) + ", ";
    std::string header = "{'descr': '<f8', 'fortran_order': False, 'shape': (" + dims + "), }";
    // Magic (6) + version (2) + length (2) + header + '\n', padded to a multiple of 64.
    size_t total = 10 + header.size() + 1;
    header.append((64 - total % 64) % 64, ' ');
    header += '\n';
    std::string out("\x93NUMPY\x01\x00", 8);
    out += char(header.size() & 0xFF);
    out += char(header.size() >> 8);
    out += header;
    out.append(reinterpret_cast<const char*>(data.data()), data.size() * sizeof(double));
    return out;
}

void put16(std::string& s, uint32_t v) {
    s += char(v & 0xFF);
    s += char((v >> 8) & 0xFF);
}
void put32(std::string& s, uint32_t v) {
    put16(s, v & 0xFFFF);
    put16(s, v >> 16);
}

// An uncompressed zip of the named .npy members: what np.savez writes.
void write_npz(const std::string& path, const std::vector<std::pair<std::string, std::string>>& members) {
    std::FILE* f = std::fopen(path.c_str(), "wb");
    if (!f) throw std::runtime_error("cannot create " + path);
    std::string central;
    uint64_t offset = 0;
    for (const auto& [name, body] : members) {
        if (body.size() >= 0xFFFFFFFFull) throw std::runtime_error("member too large for a zip without zip64");
        uint32_t crc = crc32(body);
        std::string local;
        put32(local, 0x04034b50);
        put16(local, 20);  // version needed
        put16(local, 0);   // flags
        put16(local, 0);   // stored
        put16(local, 0);   // time
        put16(local, 0x21);  // date: 1980-01-01
        put32(local, crc);
        put32(local, uint32_t(body.size()));
        put32(local, uint32_t(body.size()));
        put16(local, uint32_t(name.size()));
        put16(local, 0);
        local += name;
        put32(central, 0x02014b50);
        put16(central, 20);
        put16(central, 20);
        put16(central, 0);
        put16(central, 0);
        put16(central, 0);
        put16(central, 0x21);
        put32(central, crc);
        put32(central, uint32_t(body.size()));
        put32(central, uint32_t(body.size()));
        put16(central, uint32_t(name.size()));
        put16(central, 0);  // extra
        put16(central, 0);  // comment
        put16(central, 0);  // disk
        put16(central, 0);  // internal attributes
        put32(central, 0);  // external attributes
        put32(central, uint32_t(offset));
        central += name;
        std::fwrite(local.data(), 1, local.size(), f);
        std::fwrite(body.data(), 1, body.size(), f);
        offset += local.size() + body.size();
    }
    std::string end;
    put32(end, 0x06054b50);
    put16(end, 0);
    put16(end, 0);
    put16(end, uint32_t(members.size()));
    put16(end, uint32_t(members.size()));
    put32(end, uint32_t(central.size()));
    put32(end, uint32_t(offset));
    put16(end, 0);
    std::fwrite(central.data(), 1, central.size(), f);
    std::fwrite(end.data(), 1, end.size(), f);
    if (std::fclose(f) != 0) throw std::runtime_error("cannot write " + path);
}

std::string num(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

void write_text(const std::string& path, const Records& rec, uint64_t a, bool csv) {
    std::FILE* f = std::fopen(path.c_str(), "wb");
    if (!f) throw std::runtime_error("cannot create " + path);
    if (csv)
        std::fputs("run,step,e_1,e_2,P_1_1,P_1_2,P_2_1,P_2_2,nu_bob_1,nu_bob_2,"
                   "S_bob_1_1,S_bob_1_2,S_bob_2_1,S_bob_2_2\n", f);
    std::string line;
    for (size_t i = 0; i < rec.runs; i++)
        for (size_t k = 0; k < rec.steps; k++) {
            size_t c = i * rec.steps + k;
            const double* e = &rec.e[c * 2];
            const double* P = &rec.P[c * 4];
            const double* nu = &rec.nu[c * 2];
            const double* S = &rec.S[c * 4];
            if (csv) {
                line = std::to_string(a + i) + "," + std::to_string(k + 1);
                for (int j = 0; j < 2; j++) line += "," + num(e[j]);
                for (int j = 0; j < 4; j++) line += "," + num(P[j]);
                for (int j = 0; j < 2; j++) line += "," + num(nu[j]);
                for (int j = 0; j < 4; j++) line += "," + num(S[j]);
            } else {
                line = "{\"run\":" + std::to_string(a + i) + ",\"step\":" + std::to_string(k + 1) +
                       ",\"e\":[" + num(e[0]) + "," + num(e[1]) + "],\"P\":[[" + num(P[0]) + "," +
                       num(P[1]) + "],[" + num(P[2]) + "," + num(P[3]) + "]],\"nu_bob\":[" + num(nu[0]) +
                       "," + num(nu[1]) + "],\"S_bob\":[[" + num(S[0]) + "," + num(S[1]) + "],[" +
                       num(S[2]) + "," + num(S[3]) + "]]}";
            }
            line += '\n';
            std::fwrite(line.data(), 1, line.size(), f);
        }
    if (std::fclose(f) != 0) throw std::runtime_error("cannot write " + path);
}

// ---------------------------------------------------------------- sums in the worker

#ifdef AUTOTUNE_SUMS
// The library's last failure, as an exception naming the call.
[[noreturn]] void library_failed(const char* call) {
    throw std::runtime_error(std::string(call) + ": " + autotune_last_error());
}

// The answer line to `request` for runs [a, b): each step given to the library as it is
// computed, no records kept. It sums exactly what autotune would read from the .npz: e and
// P at every step; nu_bob and S_bob where nu_bob is not all NaN (autotune reads an all-NaN
// nu as "no measurement at this step"; this filter measures at every step, so that is only
// a filter gone NaN, which the .npz holds as NaN too); no run marked diverged (the .npz has
// no `diverged` array; a run gone NaN is stopped by autotune, from either answer, at the
// same step).
std::string sums_answer(const std::string& request, double q, double r, uint64_t seed, uint64_t a,
                        uint64_t b, size_t steps) {
    using Chunk = std::unique_ptr<AutotuneChunk, void (*)(AutotuneChunk*)>;
    Chunk chunk(autotune_chunk_new(request.c_str()), autotune_chunk_free);
    if (!chunk) library_failed("autotune_chunk_new");
    simulate(q, r, seed, a, b, steps, [&](uint64_t run, size_t step, const Step& s) {
        if (autotune_chunk_state(chunk.get(), run, step, s.e, s.P) != 0)
            library_failed("autotune_chunk_state");
        bool measured = !(std::isnan(s.nu[0]) && std::isnan(s.nu[1]));
        if (measured && autotune_chunk_sensor(chunk.get(), run, step, "bob", s.nu, s.S) != 0)
            library_failed("autotune_chunk_sensor");
    });
    char* line = autotune_chunk_answer(chunk.release());  // frees the chunk
    if (!line) library_failed("autotune_chunk_answer");
    std::string answer(line);
    autotune_string_free(line);
    return answer;
}
#endif

// ---------------------------------------------------------------- the worker loop

std::string serve(const std::string& line, const std::string& format) {
    Parser p{line};
    Json req = p.value();
    const std::string id = req.at("id").text;
    try {
        const Json& theta = req.at("theta");
        double q = theta.at("q").number(), r = theta.at("r").number();
        uint64_t seed = req.at("seed").u64();
        const Json& runs = req.at("runs");
        if (runs.items.size() != 2) throw std::runtime_error("runs is not [a, b]");
        uint64_t a = runs.items[0].u64(), b = runs.items[1].u64();
        size_t steps = req.at("steps").u64();
#ifdef AUTOTUNE_SUMS
        if (format == "sums") return sums_answer(line, q, r, seed, a, b, steps);
#endif
        const std::string& dir = req.at("dir").text;
        Records rec = records(q, r, seed, a, b, steps);
        std::string path = dir + "/" + id + "." + format;
        if (format == "npz") {
            std::vector<size_t> vec{rec.runs, rec.steps, 2}, mat{rec.runs, rec.steps, 2, 2};
            write_npz(path, {{"e.npy", npy(rec.e, vec)},
                             {"P.npy", npy(rec.P, mat)},
                             {"nu_bob.npy", npy(rec.nu, vec)},
                             {"S_bob.npy", npy(rec.S, mat)}});
        } else {
            write_text(path, rec, a, format == "csv");
        }
        return "{\"id\":" + id + ",\"file\":" + json_string(path) + "}";
    } catch (const std::exception& ex) {
        return "{\"id\":" + id + ",\"error\":" + json_string(ex.what()) + "}";
    }
}

// The worker's own work on runs [0, n) in chunks of 64, as autotune asks for them, with no
// protocol: `none` simulates and filters (a checksum keeps the results alive), `sums` also
// feeds the library and makes each chunk's answer line. One chunk first, untimed (as a
// worker serving autotune is warm). Prints the wall time in ms, then what was timed.
int self_time(const std::string& mode, size_t n, size_t steps, size_t lags) {
    const double q = 2.0, r = 0.1;  // pendulum.toml's start
    const uint64_t seed = 7;
    double checksum = 0.0;
    size_t answered = 0;
    auto chunk = [&](size_t a, size_t b) {
        if (mode == "none") {
            simulate(q, r, seed, a, b, steps, [&](uint64_t, size_t, const Step& s) {
                checksum += s.e[0] + s.e[1] + s.P[0] + s.nu[0] + s.nu[1] + s.S[0];
            });
            return;
        }
#ifdef AUTOTUNE_SUMS
        // The request autotune would send (its fields a sums answer reads).
        std::string request = "{\"id\":" + std::to_string(a / 64) + ",\"theta\":{\"q\":" + num(q) +
                              ",\"r\":" + num(r) + "},\"seed\":" + std::to_string(seed) +
                              ",\"runs\":[" + std::to_string(a) + "," + std::to_string(b) +
                              "],\"steps\":" + std::to_string(steps) + ",\"dir\":\"\",\"lags\":" +
                              std::to_string(lags) +
                              ",\"layout\":{\"state\":2,\"sensors\":[{\"name\":\"bob\",\"dim\":2}]}}";
        answered += sums_answer(request, q, r, seed, a, b, steps).size();
#else
        (void)lags;
#endif
    };
    chunk(0, std::min<size_t>(n, 64));
    checksum = 0.0;
    answered = 0;
    auto t0 = std::chrono::steady_clock::now();
    for (size_t a = 0; a < n; a += 64) chunk(a, std::min(n, a + 64));
    std::chrono::duration<double, std::milli> ms = std::chrono::steady_clock::now() - t0;
    std::printf("%.3f ms: --self-time %s, %zu runs x %zu steps in chunks of 64 (", ms.count(),
                mode.c_str(), n, steps);
    if (mode == "none")
        std::printf("checksum %.6g)\n", checksum);
    else
        std::printf("%zu answer bytes)\n", answered);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
#ifdef AUTOTUNE_SUMS
    const char* usage =
        "usage: pendulum_ekf [--format npz|csv|jsonl|sums]\n"
        "       pendulum_ekf --self-time sums|none N T [LAGS]\n";
    const std::vector<std::string> formats{"npz", "csv", "jsonl", "sums"}, modes{"sums", "none"};
#else
    const char* usage =
        "usage: pendulum_ekf [--format npz|csv|jsonl]\n"
        "       pendulum_ekf --self-time none N T\n"
        "(--format sums and --self-time sums need a build with -DAUTOTUNE_SUMS)\n";
    const std::vector<std::string> formats{"npz", "csv", "jsonl"}, modes{"none"};
#endif
    auto one_of = [](const std::vector<std::string>& set, const std::string& v) {
        return std::find(set.begin(), set.end(), v) != set.end();
    };
    if (argc >= 2 && std::string(argv[1]) == "--self-time") {
        try {
            if (argc != 5 && argc != 6) throw std::invalid_argument("arguments");
            std::string mode = argv[2];
            size_t n = std::stoull(argv[3]), steps = std::stoull(argv[4]);
            if (!one_of(modes, mode) || n == 0 || steps == 0) throw std::invalid_argument("bad value");
            size_t lags = argc == 6 ? std::stoull(argv[5]) : std::min<size_t>(5, steps - 1);
            return self_time(mode, n, steps, lags);
        } catch (const std::logic_error&) {
            std::cerr << usage;
            return 2;
        } catch (const std::exception& ex) {
            std::cerr << "pendulum_ekf: " << ex.what() << "\n";
            return 1;
        }
    }
    std::string format = "npz";
    if (argc == 3 && std::string(argv[1]) == "--format") format = argv[2];
    if (!one_of(formats, format)) {
        std::cerr << usage;
        return 2;
    }
    std::string line;
    while (std::getline(std::cin, line)) {
        if (line.empty()) continue;
        std::string answer;
        try {
            answer = serve(line, format);
        } catch (const std::exception& ex) {
            // No id to answer: say why on stderr and stop (autotune reports it).
            std::cerr << "pendulum_ekf: " << ex.what() << "\n";
            return 1;
        }
        std::cout << answer << "\n" << std::flush;
    }
    return 0;
}

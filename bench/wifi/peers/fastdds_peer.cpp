// Stock Fast DDS workload peer (Debian bookworm's Fast DDS 2.9.1, libfastrtps-dev).
//
// The same workload as cyclone_peer.py and zenoh_peer.py (bench/wifi/peers/common.py): one
// participant per drone on domain 0; a member writes Ready(member, seq) once per --period,
// the commander (index 0) reads them and records per-member counts, the wall time of the
// first and of the --messages-th sample, and the time its reader had matched N-1 writers.
// Default QoS throughout (the paper tested each DDS "with its default QoS configuration").
//
// Discovery is whatever Fast DDS does by default: SPDP multicast + SEDP (contender
// `fastdds`), or, when the harness sets ROS_DISCOVERY_SERVER, a Discovery Server client
// (contender `fastdds-server`): Fast DDS itself turns a default participant into a client of
// the servers that variable lists, as the ROS 2 "Using Fast DDS Discovery Server" tutorial
// does. The one departure from the defaults is the transport: UDPv4 only. Fast DDS adds a
// shared-memory transport by default, and the drone namespaces of this testbed share one
// /dev/shm, so participants would talk past the emulated channel; on real drones (separate
// hosts) shared memory is never used between them, so UDP only is what a swarm sees.
//
// With --events 1 (flight runs, bench/wifi/peers/common.py "FlightEvents") the participant
// carries its drone index as USER_DATA and a DomainParticipantListener reports what Fast
// DDS's participant discovery says, one JSON line on stdout per event: DISCOVERED_PARTICIPANT
// is "up", REMOVED_PARTICIPANT (the remote said goodbye) and DROPPED_PARTICIPANT (its lease,
// Fast DDS's default leaseDuration 20 s, expired) are "down", keyed by the remote's GUID. A
// Discovery Server client hears of the other clients through the server and reports them
// the same way; the server itself carries no index and is not reported.
//
// Built by scripts/setup.sh (bench/wifi/fastdds_build.py) into a gitignored cache.
// Never fuzz it: Fast DDS 2.9.1 trusts the length of its own 0x80 statistics submessage.

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>
#include <fastdds/dds/domain/qos/DomainParticipantQos.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>

#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>

using namespace eprosima::fastdds::dds;
using eprosima::fastrtps::rtps::InstanceHandle_t;
using eprosima::fastrtps::rtps::SerializedPayload_t;

namespace
{

struct Ready
{
    int32_t member = 0;
    int32_t seq = 0;
    std::string text;
};

// Ready as XCDR1 little endian: encapsulation CDR_LE, int32 member (@key), int32 seq,
// string text (length incl. NUL, bytes, NUL). Written by hand: no fastddsgen in Debian.
class ReadyType : public TopicDataType
{
public:
    ReadyType()
    {
        setName("swarmbench::Ready");
        m_typeSize = 4 + 4 + 4 + 4 + 256;
        m_isGetKeyDefined = true;
    }

    bool serialize(void* data, SerializedPayload_t* payload) override
    {
        const Ready* r = static_cast<const Ready*>(data);
        uint32_t slen = static_cast<uint32_t>(r->text.size() + 1);
        uint32_t need = 4 + 4 + 4 + 4 + slen;
        if (need > payload->max_size) return false;
        uint8_t* p = payload->data;
        const uint8_t hdr[4] = {0x00, 0x01, 0x00, 0x00};  // CDR_LE, no options
        std::memcpy(p, hdr, 4);
        std::memcpy(p + 4, &r->member, 4);
        std::memcpy(p + 8, &r->seq, 4);
        std::memcpy(p + 12, &slen, 4);
        std::memcpy(p + 16, r->text.c_str(), slen);
        payload->length = need;
        payload->encapsulation = CDR_LE;
        return true;
    }

    bool deserialize(SerializedPayload_t* payload, void* data) override
    {
        Ready* r = static_cast<Ready*>(data);
        const uint8_t* p = payload->data;
        if (payload->length < 16 || p[1] != 0x01) return false;  // only what we write
        uint32_t slen = 0;
        std::memcpy(&r->member, p + 4, 4);
        std::memcpy(&r->seq, p + 8, 4);
        std::memcpy(&slen, p + 12, 4);
        if (slen == 0 || slen > payload->length - 16) return false;
        r->text.assign(reinterpret_cast<const char*>(p + 16), slen - 1);
        return true;
    }

    std::function<uint32_t()> getSerializedSizeProvider(void* data) override
    {
        const Ready* r = static_cast<const Ready*>(data);
        return [r]() { return static_cast<uint32_t>(16 + r->text.size() + 1); };
    }

    void* createData() override { return new Ready(); }
    void deleteData(void* data) override { delete static_cast<Ready*>(data); }

    // The key (member, int32) in big-endian CDR, zero-padded to 16 octets (DDS-RTPS 9.6.3.8:
    // keys of at most 16 octets are used as is, no MD5).
    bool getKey(void* data, InstanceHandle_t* handle, bool /*force_md5*/) override
    {
        const Ready* r = static_cast<const Ready*>(data);
        uint32_t m = static_cast<uint32_t>(r->member);
        std::memset(handle->value, 0, 16);
        handle->value[0] = static_cast<uint8_t>(m >> 24);
        handle->value[1] = static_cast<uint8_t>(m >> 16);
        handle->value[2] = static_cast<uint8_t>(m >> 8);
        handle->value[3] = static_cast<uint8_t>(m);
        return true;
    }
};

std::atomic<bool> g_stop{false};

void OnSignal(int) { g_stop.store(true); }

double WallNow()
{
    return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch())
        .count();
}

struct Args
{
    int index = -1;
    int n = 0;
    double duration = 0;
    int messages = 20;
    double period = 1.0;
    std::string out;
    std::string barrier;
    bool events = false;
};

bool ParseArgs(int argc, char** argv, Args& a)
{
    for (int i = 1; i + 1 < argc; i += 2) {
        std::string k = argv[i];
        std::string v = argv[i + 1];
        if (k == "--index") a.index = std::atoi(v.c_str());
        else if (k == "--n") a.n = std::atoi(v.c_str());
        else if (k == "--duration") a.duration = std::atof(v.c_str());
        else if (k == "--messages") a.messages = std::atoi(v.c_str());
        else if (k == "--period") a.period = std::atof(v.c_str());
        else if (k == "--out") a.out = v;
        else if (k == "--barrier") a.barrier = v;
        else if (k == "--events") a.events = v == "1";
        else return false;
    }
    return a.index >= 0 && a.n >= 2 && a.duration > 0 && !a.out.empty();
}

// bench/wifi/barrier.py: connect to the harness's UNIX socket and block for one byte or EOF.
bool WaitBarrier(const std::string& path)
{
    if (path.empty()) return true;
    int fd = socket(AF_UNIX, SOCK_STREAM, 0);
    if (fd < 0) return false;
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path.c_str(), sizeof(addr.sun_path) - 1);
    if (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) {
        close(fd);
        return false;
    }
    char b;
    ssize_t got;
    do {
        got = recv(fd, &b, 1, 0);
    } while (got < 0 && errno == EINTR && !g_stop.load());
    close(fd);
    return true;
}

std::string Num(double v)
{
    std::ostringstream o;
    o.precision(17);
    o << v;
    return o.str();
}

// One event line (common.py FlightEvents: {"flight": kind, "t": wall, ...}), whole and
// flushed: the listener runs on Fast DDS's threads, the readiness snapshot on main's.
std::mutex g_out;

void Emit(const std::string& kind, const std::string& rest)
{
    std::ostringstream line;
    line << "{\"flight\": \"" << kind << "\", \"t\": " << Num(WallNow()) << rest << "}\n";
    std::lock_guard<std::mutex> lock(g_out);
    std::fputs(line.str().c_str(), stdout);
    std::fflush(stdout);
}

// The drone index a remote participant's USER_DATA carries (ASCII decimal), or -1.
int DroneIndex(const std::vector<eprosima::fastrtps::rtps::octet>& data)
{
    if (data.empty() || data.size() > 6) return -1;
    int v = 0;
    for (auto c : data) {
        if (c < '0' || c > '9') return -1;
        v = v * 10 + (c - '0');
    }
    return v;
}

class DiscoveryEvents : public DomainParticipantListener
{
public:
    explicit DiscoveryEvents(int own) : own_(own) {}

    void on_participant_discovery(
        DomainParticipant*, eprosima::fastrtps::rtps::ParticipantDiscoveryInfo&& info) override
    {
        using Info = eprosima::fastrtps::rtps::ParticipantDiscoveryInfo;
        std::ostringstream guid;
        guid << info.info.m_guid;
        std::string key = guid.str();
        std::lock_guard<std::mutex> lock(mu_);
        if (info.status == Info::DISCOVERED_PARTICIPANT) {
            int index = DroneIndex(info.info.m_userData.data_vec());
            if (index < 0 || index == own_ || seen_.count(key) || seen_.size() >= 1024) return;
            seen_[key] = index;
            Emit("up", ", \"peer\": " + std::to_string(index) + ", \"key\": \"" + key + "\"");
        } else if (info.status == Info::REMOVED_PARTICIPANT ||
                   info.status == Info::DROPPED_PARTICIPANT) {
            auto it = seen_.find(key);
            if (it == seen_.end()) return;
            Emit("down",
                 ", \"peer\": " + std::to_string(it->second) + ", \"key\": \"" + key + "\"");
            seen_.erase(it);
        }
    }

private:
    int own_;
    std::mutex mu_;
    std::map<std::string, int> seen_;  // remote GUID -> the index it announced
};

void WriteResult(const std::string& path, const std::string& json)
{
    std::string tmp = path + ".tmp";
    {
        std::ofstream f(tmp, std::ios::trunc);
        f << json;
    }
    std::rename(tmp.c_str(), path.c_str());
}

}  // namespace

int main(int argc, char** argv)
{
    Args args;
    if (!ParseArgs(argc, argv, args)) {
        std::fprintf(stderr,
                     "usage: fastdds_peer --index I --n N --duration S --out FILE "
                     "[--messages M] [--period P] [--barrier SOCK]\n");
        return 2;
    }
    std::signal(SIGTERM, OnSignal);
    std::signal(SIGINT, OnSignal);

    // everything that does not touch the network happens before the barrier
    DomainParticipantQos pqos = PARTICIPANT_QOS_DEFAULT;
    pqos.transport().use_builtin_transports = false;
    pqos.transport().user_transports.push_back(
        std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>());
    TypeSupport type(new ReadyType());
    DiscoveryEvents listener(args.index);
    if (args.events) {
        std::string own = std::to_string(args.index);
        pqos.user_data().data_vec(
            std::vector<eprosima::fastrtps::rtps::octet>(own.begin(), own.end()));
    }

    if (!WaitBarrier(args.barrier)) {
        std::fprintf(stderr, "fastdds_peer: cannot reach barrier %s\n", args.barrier.c_str());
        return 78;
    }
    if (args.events) Emit("hello", ", \"self\": " + std::to_string(args.index));
    DomainParticipant* participant = DomainParticipantFactory::get_instance()->create_participant(
        0, pqos, args.events ? &listener : nullptr, StatusMask::none());
    if (participant == nullptr) {
        std::fprintf(stderr, "fastdds_peer: create_participant failed\n");
        return 1;
    }
    double started = WallNow();
    type.register_type(participant);
    Topic* topic = participant->create_topic("swarm_ready", type.get_type_name(), TOPIC_QOS_DEFAULT);
    auto deadline = std::chrono::steady_clock::now() +
                    std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                        std::chrono::duration<double>(args.duration));
    std::ostringstream res;
    res << "{\"started\": " << Num(started) << ", \"index\": " << args.index;

    if (args.index == 0) {
        Subscriber* sub = participant->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
        // The sample type is keyed by member, and Fast DDS 2.9's DataReader default holds at
        // most 10 instances (ResourceLimitsQosPolicy: max_instances 10, max_samples 5000): with
        // 19 members the commander silently kept 10 (success 53 % at N = 20 in r1). Room for
        // every member, the other limits kept consistent (max_samples >= instances x per-instance).
        DataReaderQos rqos = DATAREADER_QOS_DEFAULT;
        rqos.resource_limits().max_instances = args.n;
        rqos.resource_limits().max_samples =
            args.n * rqos.resource_limits().max_samples_per_instance;
        DataReader* reader = sub->create_datareader(topic, rqos);
        if (reader == nullptr) {
            std::fprintf(stderr, "fastdds_peer: create_datareader failed\n");
            return 1;
        }
        std::map<int, int> counts;
        std::map<int, double> first, nth;
        double all_matched = -1;
        double next_readiness = 0;
        const std::map<int, int>& counts_by_member = counts;
        Ready sample;
        SampleInfo info;
        while (!g_stop.load() && std::chrono::steady_clock::now() < deadline) {
            while (reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
                if (!info.valid_data) continue;
                double now = WallNow();
                int c = ++counts[sample.member];
                first.emplace(sample.member, now);
                if (c == args.messages) nth[sample.member] = now;
            }
            if (all_matched < 0) {
                SubscriptionMatchedStatus st;
                reader->get_subscription_matched_status(st);
                if (st.current_count >= args.n - 1) all_matched = WallNow();
            }
            if (args.events && WallNow() >= next_readiness) {
                next_readiness = WallNow() + 1.0;
                std::ostringstream counts;
                counts << ", \"counts\": {";
                bool firstCount = true;
                for (auto& kv : counts_by_member) {
                    counts << (firstCount ? "" : ", ") << "\"" << kv.first << "\": " << kv.second;
                    firstCount = false;
                }
                counts << "}";
                Emit("readiness", counts.str());
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
        res << ", \"received\": {";
        bool firstItem = true;
        for (auto& kv : counts) {
            res << (firstItem ? "" : ", ") << "\"" << kv.first << "\": {\"count\": " << kv.second
                << ", \"first\": " << Num(first[kv.first]) << ", \"nth\": "
                << (nth.count(kv.first) ? Num(nth[kv.first]) : "null") << "}";
            firstItem = false;
        }
        res << "}, \"all_discovered\": " << (all_matched < 0 ? "null" : Num(all_matched));
    } else {
        Publisher* pub = participant->create_publisher(PUBLISHER_QOS_DEFAULT);
        DataWriter* writer = pub->create_datawriter(topic, DATAWRITER_QOS_DEFAULT);
        Ready r;
        r.member = args.index;
        r.text = "uav" + std::to_string(args.index + 1) + " ready";
        auto next = std::chrono::steady_clock::now();
        auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
            std::chrono::duration<double>(args.period));
        double matched = -1;
        while (!g_stop.load() && std::chrono::steady_clock::now() < deadline) {
            r.seq += 1;
            writer->write(&r);
            if (matched < 0) {
                PublicationMatchedStatus st;
                writer->get_publication_matched_status(st);
                if (st.current_count >= 1) matched = WallNow();
            }
            next += period;
            // short sleeps so a SIGTERM is seen within 50 ms
            while (!g_stop.load() && std::chrono::steady_clock::now() < next) {
                auto left = next - std::chrono::steady_clock::now();
                std::this_thread::sleep_for(std::min<std::chrono::steady_clock::duration>(
                    left, std::chrono::milliseconds(50)));
            }
        }
        res << ", \"sent\": " << r.seq
            << ", \"commander_matched\": " << (matched < 0 ? "null" : Num(matched));
    }
    res << "}";
    WriteResult(args.out, res.str());
    participant->delete_contained_entities();
    DomainParticipantFactory::get_instance()->delete_participant(participant);
    return 0;
}

"""The C++ half of the ns-3 channel process, compiled at run time by cppyy (``cppdef``).

Everything that runs inside ``Simulator::Run`` lives here, not in Python: a Python trace
sink would take the GIL inside the real-time loop (testbed notes, pitfall 9). The code
builds the scenario (802.11g/n ad hoc, YANS channel, log-distance loss, nodes on a line or
a grid, one ``TapBridge`` in UseLocal mode per node), hooks the Wi-Fi traces into plain
counters, classifies every PHY transmission by protocol, samples the real-time lag, writes
one link file per node once a second and a stats file at the end.
"""

from __future__ import annotations

from typing import Final

SOURCE: Final = r"""
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>
#include <chrono>

namespace swb
{
using namespace ns3;

enum Cls { DISC = 0, USER = 1, ZENOH = 2, OTHER = 3, ACKCLS = 4, NCLS = 5 };
static const char* kClsNames[NCLS] = {"rtps_discovery", "rtps_user", "zenoh", "other", "ack"};

struct NodeStats
{
    uint64_t macTx = 0, macTxDrop = 0, macRx = 0, macRxDrop = 0, macDropped = 0;
    uint64_t phyTx = 0, phyRetx = 0, phyTxDrop = 0, phyRxBegin = 0, phyRxEnd = 0;
    uint64_t phyRxDrop = 0;
    std::map<int, uint64_t> rxDropReason;
    std::map<int, uint64_t> macDropReason;
    int lastRxCls = OTHER;  // an ACK is counted with the frame it acknowledges
    double lastSignal = NAN, lastNoise = NAN;
    std::map<uint64_t, std::pair<double, double>> neigh;  // transmitter -> (signal, noise)
    uint64_t sniffed = 0;
    Mac48Address mac;
};

static std::vector<NodeStats> g_nodes;
static std::vector<std::array<uint64_t, NCLS>> g_perSec;      // frames per sim second
static std::vector<std::array<uint64_t, NCLS>> g_perSecAck;   // ACKs split by acked class
static std::vector<double> g_lagMaxPerSec;                    // ms
static std::vector<float> g_lagSamples;                       // ms, one per lag tick
static std::vector<double> g_modelSignal;                     // dBm, mean to neighbours
static std::string g_outDir;
static std::string g_stopFile;
static double g_noiseDbm = -94.0;
static double g_lagTickS = 0.005;
static double g_wallAtStart = 0.0;

static double WallNow()
{
    return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch())
        .count();
}

static uint64_t MacKey(Mac48Address a)
{
    uint8_t b[6];
    a.CopyTo(b);
    uint64_t k = 0;
    for (int i = 0; i < 6; ++i) k = (k << 8) | b[i];
    return k;
}

static void Bump(int cls, bool ackOf)
{
    size_t sec = (size_t)Simulator::Now().GetSeconds();
    if (g_perSec.size() <= sec) {
        g_perSec.resize(sec + 1, std::array<uint64_t, NCLS>{});
        g_perSecAck.resize(sec + 1, std::array<uint64_t, NCLS>{});
    }
    if (ackOf) {
        g_perSec[sec][ACKCLS]++;
        g_perSecAck[sec][cls]++;
    } else {
        g_perSec[sec][cls]++;
    }
}

// RTPS: discovery when the first submessage naming an entity names a builtin one (entity
// kind 0xC0 bits set: SPDP/SEDP writers and readers), user data otherwise. The port rule
// (PB+DG*d+{0, 10+2i} metatraffic) is only the fallback: Cyclone's default participant
// index "none" puts its unicast locators on ephemeral ports.
static int RtpsClass(const uint8_t* m, uint32_t len, uint16_t dport)
{
    uint32_t off = 20;  // RTPS header
    while (off + 4 <= len) {
        uint8_t id = m[off];
        bool le = m[off + 1] & 1;
        uint16_t sublen = le ? (uint16_t)(m[off + 2] | m[off + 3] << 8)
                             : (uint16_t)(m[off + 2] << 8 | m[off + 3]);
        const uint8_t* body = m + off + 4;
        int writerAt = -1;
        if (id == 0x15 || id == 0x16) writerAt = 8;  // DATA, DATA_FRAG: flags, octets, rd
        else if (id == 0x06 || id == 0x07 || id == 0x08 || id == 0x12 || id == 0x13)
            writerAt = 4;  // ACKNACK, HEARTBEAT, GAP, NACK_FRAG, HEARTBEAT_FRAG: reader, writer
        if (writerAt >= 0) {
            if (off + 4 + writerAt + 4 > len) break;
            uint8_t kind = body[writerAt + 3];
            return (kind & 0xC0) == 0xC0 ? DISC : USER;
        }
        if (sublen == 0) break;
        off += 4 + sublen;
    }
    int port = (dport - 7400) % 250;
    return (dport >= 7400 && (port == 0 || (port >= 10 && port % 2 == 0))) ? DISC : USER;
}

// The MPDU's class: RTPS discovery or user data (RtpsClass), zenoh (TCP, or UDP 7446/7447:
// scouting), other (ARP, IGMP, ...).
static int Classify(Ptr<const Packet> p, WifiMacHeader& hdr, bool& isData)
{
    Ptr<Packet> c = p->Copy();
    isData = false;
    if (c->GetSize() < 10) return OTHER;
    c->RemoveHeader(hdr);
    if (!hdr.IsData()) return OTHER;
    isData = true;
    uint8_t buf[320];
    uint32_t len = c->CopyData(buf, sizeof(buf));
    if (len < 8 || buf[0] != 0xAA || buf[1] != 0xAA) return OTHER;
    uint16_t et = (uint16_t)(buf[6] << 8 | buf[7]);
    if (et != 0x0800 || len < 8 + 20) return OTHER;
    const uint8_t* ip = buf + 8;
    uint32_t ihl = (ip[0] & 0x0F) * 4u;
    uint8_t proto = ip[9];
    if (proto == 6) return ZENOH;  // only zenoh opens TCP sessions in this testbed
    if (proto != 17 || len < 8 + ihl + 8) return OTHER;
    const uint8_t* udp = ip + ihl;
    uint16_t sport = (uint16_t)(udp[0] << 8 | udp[1]);
    uint16_t dport = (uint16_t)(udp[2] << 8 | udp[3]);
    if (sport == 7446 || dport == 7446 || sport == 7447 || dport == 7447) return ZENOH;
    const uint8_t* pl = udp + 8;
    uint32_t plLen = len - (8 + ihl + 8);
    if (plLen >= 20 && std::memcmp(pl, "RTPS", 4) == 0) return RtpsClass(pl, plLen, dport);
    return OTHER;
}

static void MacTx(uint32_t i, Ptr<const Packet>) { g_nodes[i].macTx++; }
static void MacTxDrop(uint32_t i, Ptr<const Packet>) { g_nodes[i].macTxDrop++; }
static void MacRx(uint32_t i, Ptr<const Packet>) { g_nodes[i].macRx++; }
static void MacRxDrop(uint32_t i, Ptr<const Packet>) { g_nodes[i].macRxDrop++; }

static void MacDropped(uint32_t i, WifiMacDropReason r, Ptr<const WifiMpdu>)
{
    g_nodes[i].macDropped++;
    g_nodes[i].macDropReason[(int)r]++;
}

static void PhyTxBegin(uint32_t i, Ptr<const Packet> p, double)
{
    NodeStats& s = g_nodes[i];
    s.phyTx++;
    WifiMacHeader hdr;
    bool isData = false;
    int cls = Classify(p, hdr, isData);
    if (hdr.IsAck()) {
        Bump(s.lastRxCls, true);
        return;
    }
    if (isData && hdr.IsRetry()) s.phyRetx++;
    Bump(cls, false);
}

static void PhyTxDrop(uint32_t i, Ptr<const Packet>) { g_nodes[i].phyTxDrop++; }

static void PhyRxBegin(uint32_t i, Ptr<const Packet>, RxPowerWattPerChannelBand)
{
    g_nodes[i].phyRxBegin++;
}

static void PhyRxEnd(uint32_t i, Ptr<const Packet> p)
{
    NodeStats& s = g_nodes[i];
    s.phyRxEnd++;
    WifiMacHeader hdr;
    bool isData = false;
    int cls = Classify(p, hdr, isData);
    if (isData && hdr.GetAddr1() == s.mac) s.lastRxCls = cls;  // we will ACK this one
}

static void PhyRxDrop(uint32_t i, Ptr<const Packet>, WifiPhyRxfailureReason r)
{
    g_nodes[i].phyRxDrop++;
    g_nodes[i].rxDropReason[(int)r]++;
}

static void Sniff(uint32_t i, Ptr<const Packet> p, uint16_t, WifiTxVector, MpduInfo,
                  SignalNoiseDbm sn, uint16_t)
{
    NodeStats& s = g_nodes[i];
    s.sniffed++;
    s.lastSignal = sn.signal;
    s.lastNoise = sn.noise;
    WifiMacHeader hdr;
    Ptr<Packet> c = p->Copy();
    if (c->GetSize() >= 10) {
        c->RemoveHeader(hdr);
        if (!hdr.IsCtl() || hdr.IsRts()) {  // ACK/CTS carry no transmitter address
            s.neigh[MacKey(hdr.GetAddr2())] = {sn.signal, sn.noise};
        }
    }
}

static void WriteAtomic(const std::string& path, const std::string& text)
{
    std::string tmp = path + ".tmp";
    {
        std::ofstream f(tmp, std::ios::trunc);
        f << text;
    }
    std::rename(tmp.c_str(), path.c_str());
}

// Once a second: each node's link file for swarmd's `file` link source. The signal is the
// mean RSSI over the neighbours heard so far (MonitorSnifferRx); before a node has heard
// anyone, the propagation model's mean over its neighbours in range ("model").
static void WriteLinks()
{
    for (size_t i = 0; i < g_nodes.size(); ++i) {
        NodeStats& s = g_nodes[i];
        double sig = 0, noise = 0;
        const char* src = "measured";
        if (!s.neigh.empty()) {
            for (auto& kv : s.neigh) {
                sig += kv.second.first;
                noise += kv.second.second;
            }
            sig /= s.neigh.size();
            noise /= s.neigh.size();
        } else {
            sig = g_modelSignal[i];
            noise = g_noiseDbm;
            src = "model";
        }
        std::ostringstream o;
        o.precision(6);
        o << "{\"signal_dbm\": " << sig << ", \"noise_dbm\": " << noise
          << ", \"snr_db\": " << (sig - noise) << ", \"neighbours\": " << s.neigh.size()
          << ", \"origin\": \"" << src << "\", \"sim_s\": " << Simulator::Now().GetSeconds()
          << "}\n";
        WriteAtomic(g_outDir + "/link-" + std::to_string(i) + ".json", o.str());
    }
    Simulator::Schedule(Seconds(1.0), &WriteLinks);
}

static void LagTick()
{
    Ptr<RealtimeSimulatorImpl> impl = DynamicCast<RealtimeSimulatorImpl>(
        Simulator::GetImplementation());
    double lagMs = (impl->RealtimeNow() - Simulator::Now()).GetSeconds() * 1000.0;
    if (lagMs < 0) lagMs = 0;
    g_lagSamples.push_back((float)lagMs);
    size_t sec = (size_t)Simulator::Now().GetSeconds();
    if (g_lagMaxPerSec.size() <= sec) g_lagMaxPerSec.resize(sec + 1, 0.0);
    if (lagMs > g_lagMaxPerSec[sec]) g_lagMaxPerSec[sec] = lagMs;
    Simulator::Schedule(Seconds(g_lagTickS), &LagTick);
}

static void PollStop()
{
    if (access(g_stopFile.c_str(), F_OK) == 0) {
        Simulator::Stop();
        return;
    }
    Simulator::Schedule(MilliSeconds(100), &PollStop);
}

static void MarkReady()
{
    std::ostringstream o;
    o.precision(17);
    o << "{\"wall_at_sim0\": " << g_wallAtStart << ", \"macs\": [";
    for (size_t i = 0; i < g_nodes.size(); ++i) {
        std::ostringstream m;
        m << g_nodes[i].mac;
        o << (i ? ", " : "") << "\"" << m.str() << "\"";
    }
    o << "]}\n";
    WriteAtomic(g_outDir + "/ready.json", o.str());
}

static void Start()
{
    // wall time at sim time 0: lets the harness map its own wall-clock events to sim seconds
    g_wallAtStart = WallNow() - Simulator::Now().GetSeconds();
}

static std::string U64Map(const std::map<int, uint64_t>& m)
{
    std::ostringstream o;
    o << "{";
    bool first = true;
    for (auto& kv : m) {
        o << (first ? "" : ", ") << "\"" << kv.first << "\": " << kv.second;
        first = false;
    }
    o << "}";
    return o.str();
}

void WriteStats(const std::string& path)
{
    std::ostringstream o;
    o.precision(17);
    o << "{\"wall_at_sim0\": " << g_wallAtStart
      << ", \"sim_end_s\": " << Simulator::Now().GetSeconds()
      << ", \"lag_tick_s\": " << g_lagTickS << ", \"classes\": [";
    for (int c = 0; c < NCLS; ++c) o << (c ? ", " : "") << "\"" << kClsNames[c] << "\"";
    o << "], \"per_second\": [";
    for (size_t s = 0; s < g_perSec.size(); ++s) {
        o << (s ? ", " : "") << "[";
        for (int c = 0; c < NCLS; ++c) o << (c ? ", " : "") << g_perSec[s][c];
        o << "]";
    }
    o << "], \"acks_per_second_by_class\": [";
    for (size_t s = 0; s < g_perSecAck.size(); ++s) {
        o << (s ? ", " : "") << "[";
        for (int c = 0; c < NCLS; ++c) o << (c ? ", " : "") << g_perSecAck[s][c];
        o << "]";
    }
    o << "], \"lag_max_ms_per_second\": [";
    for (size_t s = 0; s < g_lagMaxPerSec.size(); ++s)
        o << (s ? ", " : "") << g_lagMaxPerSec[s];
    o << "], \"lag_ms\": [";
    for (size_t s = 0; s < g_lagSamples.size(); ++s) o << (s ? "," : "") << g_lagSamples[s];
    o << "], \"nodes\": [";
    for (size_t i = 0; i < g_nodes.size(); ++i) {
        NodeStats& n = g_nodes[i];
        o << (i ? ", " : "") << "{\"mac_tx\": " << n.macTx << ", \"mac_tx_drop\": " << n.macTxDrop
          << ", \"mac_rx\": " << n.macRx << ", \"mac_rx_drop\": " << n.macRxDrop
          << ", \"mac_dropped_mpdu\": " << n.macDropped
          << ", \"mac_drop_reasons\": " << U64Map(n.macDropReason)
          << ", \"phy_tx\": " << n.phyTx << ", \"phy_retx\": " << n.phyRetx
          << ", \"phy_tx_drop\": " << n.phyTxDrop << ", \"phy_rx_begin\": " << n.phyRxBegin
          << ", \"phy_rx_end\": " << n.phyRxEnd << ", \"phy_rx_drop\": " << n.phyRxDrop
          << ", \"phy_rx_drop_reasons\": " << U64Map(n.rxDropReason)
          << ", \"neighbours_heard\": " << n.neigh.size() << ", \"sniffed\": " << n.sniffed
          << "}";
    }
    o << "]}\n";
    WriteAtomic(path, o.str());
}

// Builds the whole scenario. layout: "line" (node i at x = i * spacing) or "grid"
// (ceil(sqrt(n)) columns). standard: "g" or "n" (2.4 GHz). mcastMode: "" keeps ns-3's
// default non-unicast rate (802.11g: DSSS 1 Mbps), else a WifiMode name.
void Setup(uint32_t n, double spacing, const std::string& layout, const std::string& standard,
           const std::string& tapPrefix, const std::string& outDir, const std::string& stopFile,
           const std::string& mcastMode, double lagTickS, double txPowerDbm, double exponent,
           double refLossDb)
{
    g_outDir = outDir;
    g_stopFile = stopFile;
    g_lagTickS = lagTickS;
    GlobalValue::Bind("SimulatorImplementationType", StringValue("ns3::RealtimeSimulatorImpl"));
    GlobalValue::Bind("ChecksumEnabled", BooleanValue(true));
    Config::SetDefault("ns3::RealtimeSimulatorImpl::SynchronizationMode",
                       StringValue("BestEffort"));

    NodeContainer nodes;
    nodes.Create(n);

    WifiHelper wifi;
    YansWifiPhyHelper phy;
    YansWifiChannelHelper channel;
    channel.SetPropagationDelay("ns3::ConstantSpeedPropagationDelayModel");
    channel.AddPropagationLoss("ns3::LogDistancePropagationLossModel", "Exponent",
                               DoubleValue(exponent), "ReferenceLoss", DoubleValue(refLossDb));
    phy.SetChannel(channel.Create());
    phy.Set("TxPowerStart", DoubleValue(txPowerDbm));
    phy.Set("TxPowerEnd", DoubleValue(txPowerDbm));
    std::string dataMode, ctlMode;
    if (standard == "n") {
        wifi.SetStandard(WIFI_STANDARD_80211n);
        phy.Set("ChannelSettings", StringValue("{1, 20, BAND_2_4GHZ, 0}"));
        dataMode = "HtMcs3";
        ctlMode = "ErpOfdmRate6Mbps";
    } else {
        wifi.SetStandard(WIFI_STANDARD_80211g);
        dataMode = "ErpOfdmRate24Mbps";
        ctlMode = "ErpOfdmRate6Mbps";
    }
    if (mcastMode.empty()) {
        wifi.SetRemoteStationManager("ns3::ConstantRateWifiManager", "DataMode",
                                     StringValue(dataMode), "ControlMode", StringValue(ctlMode));
    } else {
        wifi.SetRemoteStationManager("ns3::ConstantRateWifiManager", "DataMode",
                                     StringValue(dataMode), "ControlMode", StringValue(ctlMode),
                                     "NonUnicastMode", StringValue(mcastMode));
    }
    WifiMacHelper mac;
    mac.SetType("ns3::AdhocWifiMac");
    NetDeviceContainer devices = wifi.Install(phy, mac, nodes);

    MobilityHelper mobility;
    Ptr<ListPositionAllocator> pos = CreateObject<ListPositionAllocator>();
    uint32_t cols = (uint32_t)std::ceil(std::sqrt((double)n));
    for (uint32_t i = 0; i < n; ++i) {
        if (layout == "grid") {
            pos->Add(Vector((i % cols) * spacing, (i / cols) * spacing, 0.0));
        } else {
            pos->Add(Vector(i * spacing, 0.0, 0.0));
        }
    }
    mobility.SetPositionAllocator(pos);
    mobility.SetMobilityModel("ns3::ConstantPositionMobilityModel");
    mobility.Install(nodes);

    // the model's mean received signal per node over the neighbours above the -82 dBm
    // preamble-detection threshold: the link file's value until real frames arrive
    Ptr<LogDistancePropagationLossModel> model = CreateObject<LogDistancePropagationLossModel>();
    model->SetAttribute("Exponent", DoubleValue(exponent));
    model->SetAttribute("ReferenceLoss", DoubleValue(refLossDb));
    g_nodes.assign(n, NodeStats());
    g_modelSignal.assign(n, -100.0);
    for (uint32_t i = 0; i < n; ++i) {
        double sum = 0;
        int cnt = 0;
        Ptr<MobilityModel> a = nodes.Get(i)->GetObject<MobilityModel>();
        for (uint32_t j = 0; j < n; ++j) {
            if (i == j) continue;
            Ptr<MobilityModel> b = nodes.Get(j)->GetObject<MobilityModel>();
            double rx = model->CalcRxPower(txPowerDbm, a, b);
            if (rx >= -82.0) {
                sum += rx;
                cnt++;
            }
        }
        if (cnt) g_modelSignal[i] = sum / cnt;
    }

    TapBridgeHelper tap;
    tap.SetAttribute("Mode", StringValue("UseLocal"));
    for (uint32_t i = 0; i < n; ++i) {
        Ptr<WifiNetDevice> dev = DynamicCast<WifiNetDevice>(devices.Get(i));
        g_nodes[i].mac = Mac48Address::ConvertFrom(dev->GetAddress());
        tap.SetAttribute("DeviceName", StringValue(tapPrefix + std::to_string(i)));
        tap.Install(nodes.Get(i), dev);
        Ptr<WifiMac> m = dev->GetMac();
        Ptr<WifiPhy> p = dev->GetPhy();
        m->TraceConnectWithoutContext("MacTx", MakeBoundCallback(&MacTx, i));
        m->TraceConnectWithoutContext("MacTxDrop", MakeBoundCallback(&MacTxDrop, i));
        m->TraceConnectWithoutContext("MacRx", MakeBoundCallback(&MacRx, i));
        m->TraceConnectWithoutContext("MacRxDrop", MakeBoundCallback(&MacRxDrop, i));
        m->TraceConnectWithoutContext("DroppedMpdu", MakeBoundCallback(&MacDropped, i));
        p->TraceConnectWithoutContext("PhyTxBegin", MakeBoundCallback(&PhyTxBegin, i));
        p->TraceConnectWithoutContext("PhyTxDrop", MakeBoundCallback(&PhyTxDrop, i));
        p->TraceConnectWithoutContext("PhyRxBegin", MakeBoundCallback(&PhyRxBegin, i));
        p->TraceConnectWithoutContext("PhyRxEnd", MakeBoundCallback(&PhyRxEnd, i));
        p->TraceConnectWithoutContext("PhyRxDrop", MakeBoundCallback(&PhyRxDrop, i));
        p->TraceConnectWithoutContext("MonitorSnifferRx", MakeBoundCallback(&Sniff, i));
    }
    Simulator::Schedule(Seconds(0.0), &Start);
    Simulator::Schedule(Seconds(0.0), &WriteLinks);
    Simulator::Schedule(Seconds(0.0), &LagTick);
    Simulator::Schedule(Seconds(0.0), &PollStop);
    // TapBridge opens the taps at time 0; give it a moment before saying ready
    Simulator::Schedule(Seconds(0.5), &MarkReady);
}

void Run()
{
    Simulator::Run();
}

void Destroy()
{
    Simulator::Destroy();
}
}  // namespace swb
"""

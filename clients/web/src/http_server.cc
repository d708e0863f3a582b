#include "craftscan/web/http_server.h"

#include <spdlog/spdlog.h>

#include <atomic>
#include <boost/asio/dispatch.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/asio/strand.hpp>
#include <boost/asio/thread_pool.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <boost/beast/websocket.hpp>
#include <boost/beast/websocket/ssl.hpp>
#include <deque>
#include <mutex>
#include <optional>
#include <set>
#include <thread>
#include <type_traits>
#include <vector>

#include "craftscan/web/console.h"

namespace craftscan::web {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
namespace ssl = net::ssl;
using tcp = net::ip::tcp;

constexpr auto kRequestTimeout = std::chrono::seconds(30);
constexpr int kMaxConnections = 256;
constexpr std::size_t kMaxQueuedMessages = 256;
constexpr std::size_t kMaxHeaderBytes = 16 * 1024;

const char* kSecurityPolicy =
    "default-src 'self'; img-src 'self' data: blob:; connect-src 'self' ws: wss:; "
    "style-src 'self'; script-src 'self'; object-src 'none'; base-uri 'none'; "
    "frame-ancestors 'none'; form-action 'self'";

using SslStream = beast::ssl_stream<beast::tcp_stream>;
template <class Stream>
constexpr bool kIsSsl = std::is_same_v<Stream, SslStream>;

struct Shared {
  Console* console = nullptr;
  net::thread_pool* pool = nullptr;
  std::atomic<int> connections{0};
  std::size_t max_body = 65536;
  // The WebSockets' console listeners: removed before the I/O context
  // goes, so no update is posted to a context being destroyed.
  std::mutex listeners_mutex;
  std::set<int> listeners;

  int AddListener(const std::string& station, Console::Sink sink) {
    std::lock_guard lock(listeners_mutex);
    const int id = console->AddListener(station, std::move(sink));
    listeners.insert(id);
    return id;
  }
  void RemoveListener(int id) {
    std::lock_guard lock(listeners_mutex);
    if (listeners.erase(id) > 0) console->RemoveListener(id);
  }
  void RemoveAllListeners() {
    std::lock_guard lock(listeners_mutex);
    for (int id : listeners) console->RemoveListener(id);
    listeners.clear();
  }
};

// Counts a connection while alive.
struct ConnectionSlot {
  explicit ConnectionSlot(Shared* s) : shared(s) { ++shared->connections; }
  ~ConnectionSlot() { --shared->connections; }
  Shared* shared;
};

template <class Stream>
class WebSocketSession : public std::enable_shared_from_this<WebSocketSession<Stream>> {
 public:
  WebSocketSession(Shared* shared, Stream&& stream, std::string station, std::string peer)
      : shared_(shared),
        slot_(shared),
        ws_(std::move(stream)),
        station_(std::move(station)),
        peer_(std::move(peer)) {}
  ~WebSocketSession() {
    if (listener_ != 0) shared_->RemoveListener(listener_);
  }

  void Run(http::request<http::string_body> request) {
    beast::get_lowest_layer(ws_).expires_never();
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.read_message_max(64 * 1024);
    ws_.auto_fragment(false);  // one frame per message
    ws_.async_accept(
        request, beast::bind_front_handler(&WebSocketSession::OnAccept, this->shared_from_this()));
  }

 private:
  void OnAccept(beast::error_code ec) {
    if (ec) return;
    std::weak_ptr<WebSocketSession> weak = this->shared_from_this();
    auto executor = ws_.get_executor();
    listener_ = shared_->AddListener(station_, [weak, executor](const std::string& m) {
      net::post(executor, [weak, m] {
        if (auto self = weak.lock()) self->Queue(m);
      });
    });
    DoRead();
  }

  void DoRead() {
    ws_.async_read(buffer_,
                   beast::bind_front_handler(&WebSocketSession::OnRead, this->shared_from_this()));
  }

  void OnRead(beast::error_code ec, std::size_t) {
    if (ec) {
      if (ec != websocket::error::closed) spdlog::debug("{} websocket: {}", peer_, ec.message());
      return;
    }
    const std::string text = beast::buffers_to_string(buffer_.data());
    buffer_.consume(buffer_.size());
    const std::string answer = shared_->console->HandleWebSocketMessage(text);
    if (!answer.empty()) Queue(answer);
    DoRead();
  }

  void Queue(const std::string& message) {
    if (queue_.size() >= kMaxQueuedMessages) {
      // The front may be on the wire; drop the oldest behind it.
      queue_.erase(queue_.begin() + (writing_ ? 1 : 0));
      ++dropped_;
    }
    queue_.push_back(message);
    if (!writing_) DoWrite();
  }

  void DoWrite() {
    writing_ = true;
    ws_.text(true);
    ws_.async_write(
        net::buffer(queue_.front()),
        beast::bind_front_handler(&WebSocketSession::OnWrite, this->shared_from_this()));
  }

  void OnWrite(beast::error_code ec, std::size_t) {
    writing_ = false;
    if (ec) return;
    queue_.pop_front();
    if (!queue_.empty()) DoWrite();
  }

  Shared* shared_;
  ConnectionSlot slot_;
  websocket::stream<Stream> ws_;
  beast::flat_buffer buffer_;
  std::deque<std::string> queue_;
  bool writing_ = false;
  std::size_t dropped_ = 0;
  int listener_ = 0;
  std::string station_, peer_;
};

template <class Stream>
class HttpSession : public std::enable_shared_from_this<HttpSession<Stream>> {
 public:
  template <class... Args>
  HttpSession(Shared* shared, std::string peer, Args&&... args)
      : shared_(shared), slot_(shared), stream_(std::forward<Args>(args)...), peer_(peer) {}

  void Run() {
    net::dispatch(stream_.get_executor(), [self = this->shared_from_this()] {
      if constexpr (kIsSsl<Stream>) {
        beast::get_lowest_layer(self->stream_).expires_after(kRequestTimeout);
        self->stream_.async_handshake(ssl::stream_base::server,
                                      beast::bind_front_handler(&HttpSession::OnHandshake, self));
      } else {
        self->DoRead();
      }
    });
  }

 private:
  void OnHandshake(beast::error_code ec) {
    if (ec) {
      spdlog::info("{}: TLS handshake failed: {}", peer_, ec.message());
      return;
    }
    DoRead();
  }

  void DoRead() {
    parser_.emplace();
    parser_->body_limit(shared_->max_body);
    parser_->header_limit(kMaxHeaderBytes);
    beast::get_lowest_layer(stream_).expires_after(kRequestTimeout);
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&HttpSession::OnRead, this->shared_from_this()));
  }

  HttpRequest Convert(const http::request<http::string_body>& req) const {
    HttpRequest r;
    r.method = std::string(req.method_string());
    r.target = std::string(req.target());
    for (const auto& field : req) {
      std::string name(field.name_string());
      for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      r.headers[name] = std::string(field.value());
    }
    r.body = req.body();
    r.peer = peer_;
    r.tls = kIsSsl<Stream>;
    return r;
  }

  void OnRead(beast::error_code ec, std::size_t) {
    if (ec == http::error::end_of_stream) return DoClose();
    if (ec == http::error::body_limit) {
      spdlog::warn("{}: body above {} bytes refused", peer_, shared_->max_body);
      HttpResponse r;
      r.status = 413;
      r.body = R"({"error":"the request body is too large","code":"too_large"})";
      return Send(std::move(r), false, 11);
    }
    if (ec == http::error::header_limit) {
      HttpResponse r;
      r.status = 431;
      r.body = R"({"error":"the request headers are too large","code":"too_large"})";
      return Send(std::move(r), false, 11);
    }
    if (ec) {
      if (ec != beast::error::timeout) spdlog::debug("{}: read: {}", peer_, ec.message());
      if (ec == http::error::bad_target || ec == http::error::bad_method ||
          ec == http::error::bad_field || ec == http::error::bad_version) {
        HttpResponse r;
        r.status = 400;
        r.body = R"({"error":"malformed HTTP request","code":"bad_request"})";
        return Send(std::move(r), false, 11);
      }
      return;
    }
    http::request<http::string_body> req = parser_->release();
    const bool keep_alive = req.keep_alive();
    const unsigned version = req.version();
    HttpRequest request = Convert(req);
    if (websocket::is_upgrade(req)) {
      if (request.target != "/api/ws") {
        HttpResponse r;
        r.status = 404;
        r.body = R"({"error":"WebSocket is served on /api/ws only","code":"not_found"})";
        return Send(std::move(r), false, version);
      }
      std::string station;
      HttpResponse refusal;
      if (!shared_->console->AuthorizeWebSocket(request, &station, &refusal)) {
        return Send(std::move(refusal), false, version);
      }
      std::make_shared<WebSocketSession<Stream>>(shared_, std::move(stream_), station, peer_)
          ->Run(std::move(req));
      return;
    }
    // Relaying may block: off the I/O threads.
    net::post(*shared_->pool, [self = this->shared_from_this(), request = std::move(request),
                               keep_alive, version]() mutable {
      HttpResponse response = self->shared_->console->Handle(request);
      net::post(self->stream_.get_executor(),
                [self, response = std::move(response), keep_alive, version]() mutable {
                  self->Send(std::move(response), keep_alive, version);
                });
    });
  }

  template <class Response>
  void Decorate(Response& res, const HttpResponse& r, bool keep_alive) {
    res.set(http::field::server, "craftscan-web");
    res.set(http::field::content_type, r.content_type);
    res.set("X-Content-Type-Options", "nosniff");
    res.set("X-Frame-Options", "DENY");
    res.set("Referrer-Policy", "no-referrer");
    res.set("Content-Security-Policy", kSecurityPolicy);
    if (kIsSsl<Stream>) res.set("Strict-Transport-Security", "max-age=31536000");
    for (const auto& [name, value] : r.headers) res.insert(name, value);
    res.keep_alive(keep_alive);
  }

  void Send(HttpResponse r, bool keep_alive, unsigned version) {
    if (!r.file_path.empty()) {
      beast::error_code ec;
      http::file_body::value_type body;
      body.open(r.file_path.c_str(), beast::file_mode::scan, ec);
      if (ec) {
        r.status = 404;
        r.file_path.clear();
        r.content_type = "application/json";
        r.body = R"({"error":"the file vanished","code":"not_found"})";
      } else {
        auto res = std::make_shared<http::response<http::file_body>>(
            std::piecewise_construct, std::make_tuple(std::move(body)),
            std::make_tuple(static_cast<http::status>(r.status), version));
        Decorate(*res, r, keep_alive);
        res->prepare_payload();
        return Write(res, !keep_alive);
      }
    }
    auto res = std::make_shared<http::response<http::string_body>>(
        static_cast<http::status>(r.status), version);
    Decorate(*res, r, keep_alive);
    res->body() = std::move(r.body);
    res->prepare_payload();
    Write(res, !keep_alive);
  }

  template <class Response>
  void Write(std::shared_ptr<Response> res, bool close) {
    beast::get_lowest_layer(stream_).expires_after(std::chrono::minutes(10));
    http::async_write(
        stream_, *res,
        [self = this->shared_from_this(), res, close](beast::error_code ec, std::size_t) {
          if (ec) return;
          if (close) return self->DoClose();
          self->DoRead();
        });
  }

  void DoClose() {
    if constexpr (kIsSsl<Stream>) {
      beast::get_lowest_layer(stream_).expires_after(std::chrono::seconds(5));
      stream_.async_shutdown([self = this->shared_from_this()](beast::error_code) {});
    } else {
      beast::error_code ec;
      stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
    }
  }

  Shared* shared_;
  ConnectionSlot slot_;
  Stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  std::string peer_;
};

}  // namespace

struct HttpServer::Impl {
  Shared shared;  // first: the sessions that io's destruction frees use it
  net::io_context io{2};
  ssl::context tls{ssl::context::tls_server};
  bool use_tls = false;
  tcp::acceptor acceptor{io};
  net::thread_pool pool{4};
  std::vector<std::thread> threads;

  void Accept() {
    acceptor.async_accept(net::make_strand(io), [this](beast::error_code ec, tcp::socket socket) {
      if (ec) {
        if (ec != net::error::operation_aborted) {
          spdlog::warn("accept: {}", ec.message());
          Accept();
        }
        return;
      }
      beast::error_code ignored;
      const auto remote = socket.remote_endpoint(ignored);
      const std::string peer = remote.address().to_string() + ":" + std::to_string(remote.port());
      if (shared.connections.load() >= kMaxConnections) {
        spdlog::warn("{}: refused, {} connections already", peer, kMaxConnections);
        socket.close(ignored);
      } else if (use_tls) {
        std::make_shared<HttpSession<SslStream>>(&shared, peer, std::move(socket), tls)->Run();
      } else {
        std::make_shared<HttpSession<beast::tcp_stream>>(&shared, peer, std::move(socket))->Run();
      }
      Accept();
    });
  }
};

std::unique_ptr<HttpServer> HttpServer::Start(Console* console, std::string* error) {
  auto impl = std::make_unique<Impl>();
  const WebConfig& config = console->config();
  impl->shared.console = console;
  impl->shared.pool = &impl->pool;
  impl->shared.max_body = config.max_body_bytes;
  auto fail = [&](const std::string& message) -> std::unique_ptr<HttpServer> {
    if (error) *error = message;
    return nullptr;
  };
  if (config.tls()) {
    beast::error_code ec;
    impl->tls.set_options(ssl::context::default_workarounds | ssl::context::no_sslv2 |
                          ssl::context::no_sslv3 | ssl::context::no_tlsv1 |
                          ssl::context::no_tlsv1_1);
    impl->tls.use_certificate_chain_file(config.tls_certificate, ec);
    if (ec) return fail("tls.certificate: " + config.tls_certificate + ": " + ec.message());
    impl->tls.use_private_key_file(config.tls_private_key, ssl::context::pem, ec);
    if (ec) return fail("tls.private_key: " + config.tls_private_key + ": " + ec.message());
    impl->use_tls = true;
  }
  beast::error_code ec;
  const auto address = net::ip::make_address(config.listen_host, ec);
  tcp::endpoint endpoint;
  if (ec) {
    tcp::resolver resolver(impl->io);
    const auto results =
        resolver.resolve(config.listen_host, std::to_string(config.listen_port), ec);
    if (ec || results.empty()) return fail("listen: cannot resolve '" + config.listen_host + "'");
    endpoint = *results.begin();
  } else {
    endpoint = tcp::endpoint(address, config.listen_port);
  }
  const std::string where = config.listen_host + ":" + std::to_string(config.listen_port);
  impl->acceptor.open(endpoint.protocol(), ec);
  if (!ec) impl->acceptor.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) impl->acceptor.bind(endpoint, ec);
  if (!ec) impl->acceptor.listen(net::socket_base::max_listen_connections, ec);
  if (ec) return fail("listen: cannot listen on " + where + ": " + ec.message());
  impl->Accept();
  Impl* raw = impl.get();
  for (int i = 0; i < 2; ++i) impl->threads.emplace_back([raw] { raw->io.run(); });
  return std::unique_ptr<HttpServer>(new HttpServer(std::move(impl)));
}

HttpServer::HttpServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

HttpServer::~HttpServer() {
  impl_->shared.RemoveAllListeners();
  net::post(impl_->io, [this] {
    beast::error_code ignored;
    impl_->acceptor.close(ignored);
  });
  impl_->io.stop();
  for (auto& t : impl_->threads) t.join();
  impl_->pool.join();
}

std::uint16_t HttpServer::port() const { return impl_->acceptor.local_endpoint().port(); }

}  // namespace craftscan::web

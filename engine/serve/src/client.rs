//! A minimal blocking HTTP/1.1 client for the load test and the tests: one request per
//! connection (`Connection: close`), the whole response read into memory. Enough to
//! exercise the server for real over TCP without an HTTP client dependency.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

/// A response as it came off the wire.
#[derive(Clone, Debug)]
pub struct HttpResponse {
    pub status: u16,
    /// Header names in lower case.
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl HttpResponse {
    /// The first header named `name` (case-insensitive).
    pub fn header(&self, name: &str) -> Option<&str> {
        let name = name.to_ascii_lowercase();
        self.headers
            .iter()
            .find(|(k, _)| *k == name)
            .map(|(_, v)| v.as_str())
    }

    /// The body as JSON (`Value::Null` if it is not JSON).
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body).unwrap_or(serde_json::Value::Null)
    }
}

/// Sends one request with an optional JSON body and reads the whole response.
pub fn request(
    addr: SocketAddr,
    method: &str,
    path: &str,
    json_body: Option<&[u8]>,
    timeout: Duration,
) -> std::io::Result<HttpResponse> {
    request_with_headers(addr, method, path, &[], json_body, timeout)
}

/// [`request`] with more header lines (`name`, `value`), written as given.
pub fn request_with_headers(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    json_body: Option<&[u8]>,
    timeout: Duration,
) -> std::io::Result<HttpResponse> {
    let mut head = format!("{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n");
    for (name, value) in headers {
        head += &format!("{name}: {value}\r\n");
    }
    if let Some(body) = json_body {
        head += &format!(
            "Content-Type: application/json\r\nContent-Length: {}\r\n",
            body.len()
        );
    }
    head += "\r\n";
    let mut wire = head.into_bytes();
    wire.extend_from_slice(json_body.unwrap_or_default());
    send_raw(addr, &wire, timeout)
}

/// Writes `wire` as is (for malformed requests) and reads the response.
pub fn send_raw(addr: SocketAddr, wire: &[u8], timeout: Duration) -> std::io::Result<HttpResponse> {
    let mut stream = TcpStream::connect_timeout(&addr, timeout)?;
    stream.set_read_timeout(Some(timeout))?;
    stream.set_write_timeout(Some(timeout))?;
    // A server may answer (413) and close before the whole body is written.
    let _ = stream.write_all(wire);
    let mut bytes = Vec::new();
    stream.read_to_end(&mut bytes)?;
    parse(&bytes)
}

/// The address of an `http://HOST[:PORT][/]` URL (port 80 by default; the first address
/// HOST resolves to). This client speaks plain HTTP to a server root only, so a path or
/// another scheme is refused with what was expected.
pub fn parse_http_url(url: &str) -> Result<SocketAddr, String> {
    let expected = || format!("expected http://HOST:PORT, found `{url}`");
    let rest = url.strip_prefix("http://").ok_or_else(|| {
        if url.starts_with("https://") {
            format!("{}; this client speaks plain HTTP only", expected())
        } else {
            expected()
        }
    })?;
    let host_port = rest.strip_suffix('/').unwrap_or(rest);
    if host_port.is_empty() || host_port.contains(['/', '?', '#', '@']) {
        return Err(format!("{} (no path, query or user)", expected()));
    }
    // A bare IPv6 address needs its brackets; a host without a port gets 80.
    let with_port = match host_port.rsplit_once(':') {
        Some((_, port)) if !host_port.ends_with(']') => {
            port.parse::<u16>()
                .map_err(|_| format!("{}: `{port}` is not a port", expected()))?;
            host_port.to_string()
        }
        _ => format!("{host_port}:80"),
    };
    use std::net::ToSocketAddrs;
    with_port
        .to_socket_addrs()
        .map_err(|e| format!("resolving `{host_port}`: {e}"))?
        .next()
        .ok_or_else(|| format!("`{host_port}` resolves to no address"))
}

fn bad(what: &str) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, what.to_string())
}

fn parse(bytes: &[u8]) -> std::io::Result<HttpResponse> {
    let end = bytes
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or_else(|| bad("no end of headers in the response"))?;
    let head = std::str::from_utf8(&bytes[..end]).map_err(|_| bad("non-UTF-8 headers"))?;
    let mut lines = head.split("\r\n");
    let status = lines
        .next()
        .and_then(|l| l.split(' ').nth(1))
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| bad("no status line"))?;
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    let mut response = HttpResponse {
        status,
        headers,
        body: bytes[end + 4..].to_vec(),
    };
    if response
        .header("transfer-encoding")
        .is_some_and(|v| v.eq_ignore_ascii_case("chunked"))
    {
        response.body = dechunk(&response.body)?;
    } else if let Some(n) = response
        .header("content-length")
        .and_then(|v| v.parse::<usize>().ok())
    {
        if response.body.len() < n {
            return Err(bad("response body shorter than its Content-Length"));
        }
        response.body.truncate(n);
    }
    Ok(response)
}

fn dechunk(mut b: &[u8]) -> std::io::Result<Vec<u8>> {
    let mut out = Vec::new();
    loop {
        let eol = b
            .windows(2)
            .position(|w| w == b"\r\n")
            .ok_or_else(|| bad("truncated chunk size"))?;
        let size_text = std::str::from_utf8(&b[..eol]).map_err(|_| bad("bad chunk size"))?;
        let size = usize::from_str_radix(size_text.split(';').next().unwrap_or("").trim(), 16)
            .map_err(|_| bad("bad chunk size"))?;
        b = &b[eol + 2..];
        if size == 0 {
            return Ok(out);
        }
        if b.len() < size + 2 {
            return Err(bad("truncated chunk"));
        }
        out.extend_from_slice(&b[..size]);
        b = &b[size + 2..];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_name_a_server_root() {
        let ok = |u: &str| parse_http_url(u).unwrap().to_string();
        assert_eq!(ok("http://127.0.0.1:8000"), "127.0.0.1:8000");
        assert_eq!(ok("http://127.0.0.1:8000/"), "127.0.0.1:8000");
        assert_eq!(ok("http://127.0.0.1"), "127.0.0.1:80");
        assert_eq!(ok("http://[::1]:9"), "[::1]:9");
        for bad in [
            "127.0.0.1:8000",
            "https://127.0.0.1:8000",
            "http://",
            "http://127.0.0.1:8000/render",
            "http://127.0.0.1:port",
            "http://127.0.0.1:99999",
            "http://u@127.0.0.1:1",
        ] {
            let e = parse_http_url(bad).unwrap_err();
            assert!(e.contains("expected http://HOST:PORT"), "{bad}: {e}");
        }
    }

    #[test]
    fn parses_length_and_chunked_bodies() {
        let r = parse(
            b"HTTP/1.1 503 Service Unavailable\r\nRetry-After: 2\r\ncontent-length: 2\r\n\r\n{}",
        )
        .unwrap();
        assert_eq!(r.status, 503);
        assert_eq!(r.header("retry-after"), Some("2"));
        assert_eq!(r.body, b"{}");
        let r = parse(
            b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n3\r\nabc\r\n2\r\nde\r\n0\r\n\r\n",
        )
        .unwrap();
        assert_eq!(r.body, b"abcde");
    }
}

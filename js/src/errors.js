/**
 * Named errors of the decoder, the kinds of spec/README.md "Kinds of refusal". Every failure on input bytes is a
 * PmwError subclass, and so are the three.js plugin's failures to get a stream (FetchError) or to match it to the
 * document three.js parsed (StreamMismatchError):
 *
 *   PmwError
 *   ├── FormatError            the bytes break the format (spec/README.md, spec/bitstream.md)
 *   │   ├── LimitError         a declared size or count is over a limit (README "Limits")
 *   │   └── UnsupportedError   a version / payload codec / GLB container version this reader does not implement
 *   ├── CorruptChunkError      a chunk's stored bytes do not match its BLAKE2b digest, or (chunk
 *   │                          null) the decoded base mesh does not match its baseDigest
 *   ├── TruncatedError         the stream ended before the base mesh was complete
 *   ├── DracoError             the Draco base mesh could not be decoded
 *   ├── FetchError             (three.js plugin) the stream could not be fetched: an HTTP status that is no answer
 *   │                          to the request (404, 500; `.status`), or a network failure (`.status` undefined,
 *   │                          `.cause` the fetch API's error); `.url`. Not a fault of the file's bytes: retry later
 *   └── StreamMismatchError    (three.js plugin) the stream read from `options.url` is not the document three.js
 *                              parsed (its PMWM_progressive_mesh objects differ: another file, or another version)
 *
 * Misuse of the push decoder (feed() after close()) is a TypeError, as writing to a closed WritableStream is.
 */
export class PmwError extends Error {
  constructor(message, options) {
    super(message, options);
    this.name = this.constructor.name;
  }
}
export class FormatError extends PmwError {}
export class LimitError extends FormatError {}
export class UnsupportedError extends FormatError {}
export class CorruptChunkError extends PmwError {
  /**
   * @param {number|null} chunk the chunk's number in stream order, from 1 as in the message, the levels (level k is
   *   reached by chunk k) and pmwm_codec's ChecksumError.chunk; null for the base mesh
   */
  constructor(message, chunk) {
    super(message);
    this.chunk = chunk;
  }
}
export class TruncatedError extends PmwError {
  constructor(message, bytesReceived, bytesNeeded) {
    super(message);
    this.bytesReceived = bytesReceived;
    this.bytesNeeded = bytesNeeded;
  }
}
export class DracoError extends PmwError {}
export class FetchError extends PmwError {
  /** @param {{url?: string, status?: number, cause?: unknown}} details */
  constructor(message, { url, status, cause } = {}) {
    super(message, cause === undefined ? undefined : { cause });
    this.url = url;
    this.status = status;
  }
}
export class StreamMismatchError extends PmwError {
  constructor(message, url) {
    super(message);
    this.url = url;
  }
}

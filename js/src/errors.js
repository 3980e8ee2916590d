/**
 * Named errors of the decoder, the kinds of spec/README.md "Kinds of refusal". Every failure on input bytes is a
 * PmwError subclass:
 *
 *   PmwError
 *   ├── FormatError            the bytes break the format (spec/README.md, spec/bitstream.md)
 *   │   ├── LimitError         a declared size or count is over a limit (README "Limits")
 *   │   └── UnsupportedError   a version / payload codec / GLB container version this reader does not implement
 *   ├── CorruptChunkError      a chunk's stored bytes do not match its BLAKE2b digest, or (chunk
 *   │                          null) the decoded base mesh does not match its baseDigest
 *   ├── TruncatedError         the stream ended before the base mesh was complete
 *   └── DracoError             the Draco base mesh could not be decoded
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
  /** @param {number|null} chunk stream index of the chunk (0-based); null for the base mesh */
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

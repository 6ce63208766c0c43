"""Reading a recorded bag back for the tests (not a test module): the mcap reader with the
mcap_ros2 decoder, the way the recording tests and the console's session test check a bag."""
from pathlib import Path


def read_bag(mcap_path: Path):
    """(header, summary, metadata records, [(topic, schema, channel, decoded message, log_time)])."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    with open(mcap_path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header, summary = reader.get_header(), reader.get_summary()
        records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        messages = [(c.topic, s, c, d, m.log_time) for s, c, m, d in reader.iter_decoded_messages()]
    return header, summary, records, messages

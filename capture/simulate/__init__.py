"""A simulated speaker in front of a simulated iPhone: paired speech, ARKit blendshapes and phone
alignments, written as Live Link Face take folders (``s2a-capture simulate``)."""

from capture.lazy_package import lazy_package

# Imported on first use (PEP 562): ``s2a-capture`` registers the subcommand through this package, and
# every other subcommand would otherwise pay for importing scipy.signal (about a second) at start-up.
__all__ = lazy_package(
    __name__,
    {
        "Articulation": "articulation",
        "articulate": "articulation",
        "ARTIFACT_NAMES": "artifacts",
        "Artifacts": "artifacts",
        "INVENTORIES": "phones",
        "Inventory": "phones",
        "Phone": "phones",
        "inventory": "phones",
        "viseme_matrix": "phones",
        "Utterance": "prosody",
        "plan_utterance": "prosody",
        "SIMULATION_FILE": "session",
        "SimulatedTake": "session",
        "TakeSpec": "session",
        "plan_session": "session",
        "simulate": "session",
        "simulate_take": "session",
        "write_take_folder": "session",
        "Speaker": "speaker",
        "draw_speaker": "speaker",
        "synthesize": "voice",
    },
)

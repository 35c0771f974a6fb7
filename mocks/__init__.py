"""hil.mocks: simulated plants and simulated devices answering on the other side of real transports."""

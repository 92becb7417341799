"""The interactive viewer: glfw window, moderngl blit, imgui panel, input, state and the render worker."""
